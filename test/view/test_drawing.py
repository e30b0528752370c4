"""What the browser view draws (view/drawing.py) read back from our URDF: the tree is the frame
tree's, every visual is there, each rod's stroke is its prismatic limits; a URDF that is not one
is a one-line error naming /robot_description. And /tf as a bag holds it decodes without
tf2_msgs (ros/cdr.py's decoder, against its encoder)."""
import numpy as np
import pytest

from mobile_manip_sim.ros.cdr import tf_message_cdr, tf_message_transforms
from mobile_manip_sim.ros.frames import FrameTree
from mobile_manip_sim.ros.urdf import robot_description
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import load_scene
from mobile_manip_sim.view.drawing import read_urdf
from test_urdf import SCENES


@pytest.mark.parametrize("name", ["paper", "random_5"])
def test_the_drawing_is_the_frame_tree_with_its_shapes_and_strokes(name):
    scene = SCENES[name]
    tree = FrameTree(scene.robot)
    drawing = read_urdf(robot_description(scene))
    assert drawing.root == tree.root
    assert drawing.parent == {joint.child: joint.parent for joint in tree.joints}
    model = scene.robot
    rods = [drawing.visuals[f"arm_rod_{k}"] for k in range(1, model.n_links + 1)]
    assert all(len(shapes) == 1 and shapes[0].kind == "cylinder" for shapes in rods)
    assert [shapes[0].size[1] for shapes in rods] == pytest.approx(list(model.length))
    assert np.array([(s.lower[0], s.upper[0]) for s in drawing.strokes]) == pytest.approx(
        np.array(model.stroke, dtype=float))
    assert all(s.lower[1:] == (0.0, 0.0) for s in drawing.strokes)
    assert drawing.path("tip").startswith("/base_footprint/base_link/arm_link_1/arm_rod_1")
    assert drawing.meshes == 0


@pytest.mark.parametrize("text, problem", [
    ("not xml <", "not a URDF"),
    ("<robot name='r'/>", "no <robot> with a <link>"),
    ("<robot><link name='a'/><joint name='j' type='fixed'><parent link='a'/>"
     "<child link='b'/></joint></robot>", "joint 'j' joins links that are not in the URDF"),
    ("<robot><link name='a'/><link name='b'/><joint name='j' type='fixed'><parent link='a'/>"
     "<child link='b'/></joint><joint name='k' type='fixed'><parent link='b'/>"
     "<child link='a'/></joint></robot>", "not a tree"),
    ("<robot><link name='a'><visual><geometry><box size='1 x 1'/></geometry></visual></link>"
     "</robot>", "box size: '1 x 1' is not 3 numbers"),
])
def test_a_urdf_that_is_not_one_is_a_one_line_error(text, problem):
    with pytest.raises(UserError) as caught:
        read_urdf(text)
    assert caught.value.key == "/robot_description" and problem in str(caught.value)
    assert "\n" not in str(caught.value)


def test_tf_decodes_as_it_was_encoded():
    scene = load_scene()
    tree = FrameTree(scene.robot, prefix="robot1/")
    q = np.array(scene.initial_q, dtype=float) + 0.3
    transforms = [tree.base_transform(q)] + tree.moving_transforms(q)
    decoded = tf_message_transforms(tf_message_cdr(1_500_000_007, transforms))
    assert [stamp for stamp, _ in decoded] == [1_500_000_007] * len(transforms)
    assert [tuple(t) for _, t in decoded] == [(t.parent, t.child, tuple(t.translation),
                                               tuple(t.rotation)) for t in transforms]
    data = tf_message_cdr(0, transforms)
    for damaged in (data[:len(data) // 2], b"\x07" + data[1:], data[:4] + b"\xff\xff\xff\x7f"):
        with pytest.raises(ValueError):
            tf_message_transforms(damaged)
