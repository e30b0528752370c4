"""`plot` draws every figure of a run, from a `simulate` CSV and from a recorded bag: the curves
are there (counted on the returned Figure objects, not guessed from file sizes), they carry the
run's data (a bag and a CSV of the same run give the same curves), the PNGs are real images,
index.html shows them all, and bad input is a one-line error with status 2."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread
from nav_msgs.msg import Odometry
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from mobile_manip_sim.engine.simulation import DEFAULT_WHEEL_SPEED_GAINS, Simulation
from mobile_manip_sim.plot import cli as plot_cli
from mobile_manip_sim.plot.energy import impact_losses, work
from mobile_manip_sim.plot.figures import HEADING_MARKS, RESIDUAL_FLOOR, plot
from mobile_manip_sim.recording.bag_writer import BagWriter, qos_yaml
from mobile_manip_sim.recording.headless import HeadlessRecorder
from mobile_manip_sim.recording.run import load_run
from mobile_manip_sim.runtime.headless import run as simulate_run
from mobile_manip_sim.runtime.timeline import sample_times
from mobile_manip_sim.scene.coordinates import (
    ARM_U,
    JOINTS,
    OMEGA,
    WHEELS,
    YAW,
    V,
    X,
    Y,
    q_slide,
    q_turn,
    u_turn,
)
from mobile_manip_sim.scene.errors import EXIT_USER_ERROR
from mobile_manip_sim.scene.loading import load_scene, parse_scene

BIN = Path(sys.executable).parent
SAMPLE_RATE = 100.0
FIGURE_NAMES = ["joint_angles", "joint_rates", "extensions", "extension_rates", "base_path",
                "constraints", "energy"]


# --- runs -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def paper_csv(tmp_path_factory):
    """The paper run, made by the `simulate` executable."""
    out = tmp_path_factory.mktemp("paper") / "paper.csv"
    subprocess.run([str(BIN / "simulate"), "--out", str(out), "--sample-rate", str(SAMPLE_RATE)],
                   check=True, capture_output=True, text=True, timeout=120)
    return out


def _stamp(t: float):
    ns = round(t * 1e9)
    return {"sec": ns // 10**9, "nanosec": ns % 10**9}


def _plain(value):
    """numpy scalars (Impact.resting is a numpy bool) as plain JSON values."""
    return value.item()


def record_bag(path: Path, scene, duration: float) -> Simulation:
    """Record a run with the real recorder, as `simulate --record` does."""
    recorder = HeadlessRecorder(path, scene, scene.integrator, SAMPLE_RATE, duration)
    try:
        sim = simulate_run(scene, duration, SAMPLE_RATE, on_sample=recorder.sample)
    finally:
        recorder.close()
    return sim


def write_bag(path: Path, scene, duration: float, joint_states=True) -> Simulation:
    """Recorded by the real recorder; with joint_states=False a hand-built damaged bag (no
    /joint_states), which the recorder never writes."""
    if joint_states:
        return record_bag(path, scene, duration)
    sim = Simulation(scene)
    names = scene.robot.joint_names()
    with BagWriter(path) as bag:
        topics = {"/clock": "rosgraph_msgs/msg/Clock", "/odom": "nav_msgs/msg/Odometry",
                  "/wheel_effort_controller/commands": "std_msgs/msg/Float64MultiArray",
                  "/arm_effort_controller/commands": "std_msgs/msg/Float64MultiArray"}
        if joint_states:
            topics["/joint_states"] = "sensor_msgs/msg/JointState"
        for topic, type_name in topics.items():
            bag.add_topic(topic, type_name, qos_yaml())
        bag.write("/wheel_effort_controller/commands",
                  serialize_message(Float64MultiArray(data=scene.wheel_efforts.tolist())), 0)
        bag.write("/arm_effort_controller/commands",
                  serialize_message(Float64MultiArray(data=scene.joint_efforts.tolist())), 0)
        for t in sample_times(duration, SAMPLE_RATE):
            sim.advance_to(t)
            log_ns = round(t * 1e9)
            stamp = _stamp(sim.t)
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = stamp["sec"], stamp["nanosec"]
            bag.write("/clock", serialize_message(clock), log_ns)
            q, u, qdot = sim.q, sim.u, sim.qdot()
            if joint_states:
                state = JointState(name=names,
                                   position=q[JOINTS].tolist(),
                                   velocity=[*qdot[WHEELS].tolist(), *u[ARM_U].tolist()],
                                   effort=[*sim.wheel_efforts.tolist(),
                                           *sim.joint_efforts.tolist()])
                state.header.stamp.sec, state.header.stamp.nanosec = stamp["sec"], stamp["nanosec"]
                bag.write("/joint_states", serialize_message(state), log_ns)
            odometry = Odometry(child_frame_id="base_link")
            odometry.header.frame_id = "odom"
            odometry.header.stamp.sec = stamp["sec"]
            odometry.header.stamp.nanosec = stamp["nanosec"]
            odometry.pose.pose.position.x, odometry.pose.pose.position.y = float(q[X]), float(q[Y])
            odometry.pose.pose.orientation.z = math.sin(q[YAW] / 2)
            odometry.pose.pose.orientation.w = math.cos(q[YAW] / 2)
            odometry.twist.twist.linear.x = float(u[V])
            odometry.twist.twist.angular.z = float(u[OMEGA])
            bag.write("/odom", serialize_message(odometry), log_ns)
        bag.add_attachment("scene.yaml", "application/yaml", scene.to_yaml().encode())
        impacts = json.dumps([impact.as_dict() for impact in sim.impacts], default=_plain)
        bag.add_attachment("impacts.json", "application/json", impacts.encode())
        bag.add_metadata("mobile_manip_sim", {"scene": scene.name})
    return sim


@pytest.fixture(scope="module")
def paper_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("bag") / "paper_bag"
    scene = load_scene()
    sim = write_bag(path, scene, scene.duration)
    return path, sim


# --- checks shared by every input kind --------------------------------------------------------

def impacted_links(run) -> set:
    return {impact["link"] for impact in run.impacts}


def check_figures(figures, run):
    """Every figure exists with the expected number and kind of curves."""
    n = run.n_links
    assert list(figures) == FIGURE_NAMES
    for name, figure in figures.items():
        assert run.scene.name in figure.get_suptitle(), name
        assert "(" in figure.axes[-1].get_xlabel(), f"{name}: x label without a unit"
        for axes in figure.axes:
            assert "(" in axes.get_ylabel(), f"{name}: y label without a unit"
    hit = impacted_links(run)

    def lines(name, index=0):
        return figures[name].axes[index].get_lines()

    def legend(name, index=0):
        return [text.get_text() for text in figures[name].axes[index].get_legend().get_texts()]

    assert len(lines("joint_angles")) == n
    assert len(lines("joint_rates")) == n
    assert len(lines("extensions")) == n + 2 * n + len(hit)
    assert len(lines("extension_rates")) == n + len(hit)
    for name, joint in (("joint_angles", "arm_revolute"), ("extensions", "arm_prismatic")):
        for i in range(1, n + 1):
            assert any(f"{joint}_{i}" in text for text in legend(name)), (name, i)
    for i, k in enumerate(range(1, n + 1)):  # the data: q_k, l_k, q̇_k, l̇_k against t
        np.testing.assert_array_equal(lines("joint_angles")[i].get_ydata(), run.q[:, q_turn(k)])
        np.testing.assert_array_equal(lines("extensions")[i].get_ydata(), run.q[:, q_slide(k)])
        np.testing.assert_array_equal(lines("joint_rates")[i].get_ydata(), run.u[:, u_turn(k)])
        np.testing.assert_array_equal(lines("extension_rates")[i].get_xdata(), run.t)

    # the stroke ends, dashed, at the scene's limits
    strokes = sorted(float(line.get_ydata()[0]) for line in lines("extensions")[n:3 * n])
    assert strokes == sorted(np.asarray(run.scene.robot.stroke).ravel().tolist())
    assert all(line.get_linestyle() == "--" for line in lines("extensions")[n:3 * n])
    # the impacts, marked at their stop and time
    markers = lines("extensions")[3 * n:]
    assert sum(len(line.get_xdata()) for line in markers) == len(run.impacts)
    for impact in run.impacts:
        low, high = run.scene.robot.stroke[impact["link"] - 1]
        stop = low if impact["stop"] == "lower" else high
        assert any(np.any((np.asarray(line.get_xdata()) == impact["time"])
                          & (np.asarray(line.get_ydata()) == stop)) for line in markers)

    path_lines = lines("base_path")
    assert len(path_lines) == (3 if n else 2)     # base, tip (with an arm), start markers
    np.testing.assert_array_equal(path_lines[0].get_xdata(), run.q[:, X])
    arrows = figures["base_path"].axes[0].collections
    assert len(arrows) == 1 and 3 <= len(arrows[0].get_offsets()) <= HEADING_MARKS + 1
    assert figures["base_path"].axes[0].get_aspect() == 1.0

    constraints = figures["constraints"].axes[0]
    assert constraints.get_yscale() == "log" and len(constraints.get_lines()) == 2
    for line in constraints.get_lines():
        values = np.asarray(line.get_ydata())
        assert len(values) == len(run.t) and values.min() >= RESIDUAL_FLOOR
        assert values.max() < 1e-12  # the constraints hold to round-off

    top, bottom = figures["energy"].axes
    assert len(top.get_lines()) == 3 and len(bottom.get_lines()) == 1
    return bottom.get_lines()[0].get_ydata()


def check_files(out: Path):
    index = (out / "index.html").read_text()
    for name in FIGURE_NAMES:
        png = out / f"{name}.png"
        assert png.stat().st_size > 15_000, name
        pixels = imread(png)
        assert pixels.shape[0] > 300 and pixels.shape[1] > 600, name
        assert pixels[..., :3].std() > 0.05, f"{name}.png is blank"
        assert f'src="{name}.png"' in index
    assert index.count("<img") == len(FIGURE_NAMES)


# --- the tests --------------------------------------------------------------------------------

def test_paper_csv_gives_every_figure_with_its_curves(paper_csv, tmp_path):
    run = load_run(paper_csv)
    assert run.kind == "csv" and run.n_links == 2 and len(run.t) == 151
    assert impacted_links(run) == {1, 2}  # the paper run hits both stops (see its scene file)
    figures = plot(paper_csv, tmp_path / "figures")
    balance = check_figures(figures, run)
    # W rebuilt from 100 Hz samples agrees with T + V and the impact losses to a few mJ
    assert np.abs(balance).max() < 5e-3
    check_files(tmp_path / "figures")


def test_bag_gives_the_same_figures_as_the_csv_of_the_same_run(paper_bag, paper_csv, tmp_path):
    path, sim = paper_bag
    run = load_run(path)
    assert run.kind == "bag" and run.effort_source == ("/wheel_effort_controller/commands and "
                                                       "/arm_effort_controller/commands")
    assert len(run.impacts) == len(sim.impacts) == 3   # rod 2, rod 1 (throwing rod 2 off), rod 2
    figures = plot(path, tmp_path / "figures")
    balance = check_figures(figures, run)
    assert np.abs(balance).max() < 5e-3
    check_files(tmp_path / "figures")
    csv_run = load_run(paper_csv)
    np.testing.assert_allclose(run.t, csv_run.t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(run.q, csv_run.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.u, csv_run.u, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.energy, csv_run.energy, rtol=0, atol=1e-12)
    assert run.impacts == csv_run.impacts


def test_every_title_of_every_figure_fits_inside_it(paper_bag, paper_csv):
    """The energy figure's subtitle ran past both edges for a bag (its effort source is long)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from mobile_manip_sim.plot.figures import make_figures
    for source in (paper_csv, paper_bag[0]):
        for name, figure in make_figures(load_run(source)).items():
            renderer = FigureCanvasAgg(figure).get_renderer()
            figure.draw(renderer)
            titles = [figure._suptitle] + [axes.title for axes in figure.axes]
            for title in filter(None, titles):
                if not title.get_text():
                    continue
                box = title.get_window_extent(renderer)
                assert 0 <= box.x0 and box.x1 <= figure.bbox.width, (name, title.get_text())
                assert 0 <= box.y0 and box.y1 <= figure.bbox.height, (name, title.get_text())


def test_the_plot_executable_writes_png_files_and_index(paper_csv, tmp_path):
    out = tmp_path / "out"
    result = subprocess.run([str(BIN / "plot"), str(paper_csv), "--out", str(out)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "7 figures" in result.stdout
    check_files(out)


def test_a_base_only_run_draws_its_path_and_empty_arm_figures(tmp_path):
    """n = 0 links: the arm figures say so instead of failing; the bag's efforts come from the
    controllers' commands when /joint_states carries none."""
    doc = load_scene().document
    doc = {**doc, "robot": {"base": doc["robot"]["base"]}, "initial": {}, "efforts":
           {"wheels": [0.3, 0.1]}, "effects": {"wheel_damping": 0.01}}
    scene = parse_scene(doc, "base_only")
    write_bag(tmp_path / "bag", scene, 0.5)
    run = load_run(tmp_path / "bag")
    assert run.n_links == 0 and run.q.shape[1] == 5 and run.u.shape[1] == 2
    figures = plot(tmp_path / "bag", tmp_path / "figures")
    balance = check_figures(figures, run)
    assert np.abs(balance).max() < 1e-4     # smooth run, damped: W includes the damping
    assert abs(run.q[-1, 2]) > 0.1          # it turned


def test_bag_efforts_fall_back_to_the_controller_commands(tmp_path):
    """Without efforts in /joint_states, the recorded commands are held from their log time."""
    scene = load_scene()
    sim = Simulation(scene)
    sim.advance_to(0.05)
    path = tmp_path / "bag"
    with BagWriter(path) as bag:
        bag.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        bag.add_topic("/odom", "nav_msgs/msg/Odometry")
        bag.add_topic("/wheel_effort_controller/commands", "std_msgs/msg/Float64MultiArray")
        for k in range(3):
            state = JointState(name=scene.robot.joint_names(), position=[0.0] * 6,
                               velocity=[0.0] * 6)
            state.header.stamp.nanosec = k * 10_000_000
            bag.write("/joint_states", serialize_message(state), k * 10_000_000 + 1)
            odometry = Odometry()
            odometry.header.stamp.nanosec = k * 10_000_000
            odometry.pose.pose.orientation.w = 1.0
            bag.write("/odom", serialize_message(odometry), k * 10_000_000 + 1)
        bag.write("/wheel_effort_controller/commands",
                  serialize_message(Float64MultiArray(data=[1.0, -1.0])), 15_000_000)
        bag.add_attachment("scene.yaml", "application/yaml", scene.to_yaml().encode())
    run = load_run(path)
    assert run.effort_source == "/wheel_effort_controller/commands"
    np.testing.assert_array_equal(run.efforts[:, :2], [[0.1, 0.2], [0.1, 0.2], [1.0, -1.0]])
    np.testing.assert_array_equal(run.efforts[:, 2:], np.tile(scene.joint_efforts, (3, 1)))
    assert run.impacts == []


# --- bad input: one line, status 2 ------------------------------------------------------------

def _drop_columns(source: Path, target: Path, names):
    lines = source.read_text().splitlines()
    header = lines[0].split(",")
    keep = [i for i, name in enumerate(header) if name not in names]
    rows = (",".join(line.split(",")[i] for i in keep) for line in lines)
    target.write_text("\n".join(rows) + "\n")


def bad_inputs(tmp_path: Path, paper_csv: Path) -> dict:
    cases = {"missing file": ([str(tmp_path / "nothing.csv")], "no such file")}
    _drop_columns(paper_csv, tmp_path / "cut.csv", {"l2", "energy"})
    cases["missing columns"] = ([str(tmp_path / "cut.csv")], "missing columns l2, energy")
    bad_number = tmp_path / "bad_number.csv"
    bad_number.write_text(paper_csv.read_text().replace("\n0.01,", "\nzero,", 1))
    cases["not a number"] = ([str(bad_number)], "line 3, column t")
    (tmp_path / "run.txt").write_text("t\n0\n")
    cases["unknown suffix"] = ([str(tmp_path / "run.txt")], "unknown kind of run '.txt'")
    write_bag(tmp_path / "no_joint_states", load_scene(), 0.02, joint_states=False)
    cases["bag without /joint_states"] = ([str(tmp_path / "no_joint_states")],
                                          "no /joint_states topic")
    (tmp_path / "empty_dir").mkdir()
    cases["not a bag"] = ([str(tmp_path / "empty_dir")], "not a rosbag2 MCAP bag")
    cases["bad scene"] = ([str(paper_csv), "--scene", str(tmp_path / "none.yaml")],
                          "cannot read scene file")
    return cases


def test_bad_input_is_one_line_and_status_2(paper_csv, tmp_path, capsys):
    for case, (argv, message) in bad_inputs(tmp_path, paper_csv).items():
        status = plot_cli.main([*argv, "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert status == EXIT_USER_ERROR, case
        assert err.count("\n") == 1 and message in err, (case, err)
    assert not (tmp_path / "out").exists()


def test_the_executable_reports_bad_input_in_one_line(paper_csv, tmp_path):
    _drop_columns(paper_csv, tmp_path / "cut.csv", {"qd1"})
    result = subprocess.run([str(BIN / "plot"), str(tmp_path / "cut.csv"), "--out",
                             str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert result.returncode == EXIT_USER_ERROR
    assert result.stderr.startswith("plot: error: ") and result.stderr.count("\n") == 1
    assert "missing column qd1" in result.stderr


# --- the Foxglove layout shipped beside the figures -------------------------------------------

def _panels(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert node["direction"] in ("row", "column") and 0 < node["splitPercentage"] < 100
    return _panels(node["first"]) + _panels(node["second"])


def test_foxglove_layout_plots_the_recorded_topics_by_joint_name():
    """config/foxglove_layout.json: every panel of the tree is configured, its message paths
    name topics the simulator records, and /joint_states indices match the joint names."""
    layout = json.loads((Path(__file__).resolve().parents[2] / "config"
                         / "foxglove_layout.json").read_text())
    panels = _panels(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"])
    assert {panel.split("!")[0] for panel in panels} == {"3D", "Plot", "RawMessages"}
    three_d = layout["configById"][next(p for p in panels if p.startswith("3D!"))]
    assert three_d["followTf"] == "odom"
    assert three_d["topics"]["/robot_description"]["visible"] is True
    names = load_scene().robot.joint_names()
    plotted = set()
    for panel in panels:
        if not panel.startswith("Plot!"):
            continue
        config = layout["configById"][panel]
        paths = config["paths"] + ([config["xAxisPath"]] if "xAxisPath" in config else [])
        for path in paths:
            topic = path["value"].split(".")[0]
            assert topic in ("/joint_states", "/odom"), path
            if topic == "/odom":   # /odom's child frame is base_frame: base_footprint
                assert "base_link" not in path.get("label", "") + config["title"], path
            if topic == "/joint_states":
                field, index = path["value"][len(topic) + 1:-1].split("[")
                assert field in ("position", "velocity", "effort")
                assert path["label"].startswith(names[int(index)]), path
                plotted.add((field, names[int(index)]))
    assert {(field, name) for field in ("position", "velocity") for name in names[2:]} <= plotted


# --- a node's bag: efforts over each interval from the time line ------------------------------

def record_node_bag(path: Path, scene, sent: dict, timeout_ns: int, duration: float,
                    gains=None):
    """A bag in the node's format, by the node's rules (timeline.py) and the real recorder:
    zero efforts at t = 0, commands ``sent`` {stamp ns: (base, arm)} taken at that segment
    start, timing out after ``timeout_ns``; each state recorded as published. With wheel-speed
    ``gains`` (kp, ki) the base takes velocity commands (v, ω), as with base_command velocity."""
    from mobile_manip_sim.recording.recorder import RunRecorder
    from mobile_manip_sim.ros.messages import state_messages
    from mobile_manip_sim.runtime.timeline import (
        CommandSlot,
        Grid,
        apply_commands,
        start_node_time_line,
    )

    grid = Grid(SAMPLE_RATE)
    sim = Simulation(scene)
    metadata = {"source": "node", "publish_rate": repr(SAMPLE_RATE)}
    if gains is not None:
        sim.set_wheel_speed_gains(*gains)
        metadata.update(base_command="velocity", wheel_speed_kp=repr(gains[0]),
                        wheel_speed_ki=repr(gains[1]))
    start_node_time_line(sim)
    slots = CommandSlot(2), CommandSlot(sim.nu - 2)
    recorder = RunRecorder(path, scene, scene.integrator, metadata)
    try:
        for k in range(int(duration * SAMPLE_RATE)):
            stamp = grid.stamp(k)
            recorder.states(stamp, state_messages(sim, stamp, scene.robot.joint_names()))
            recorder.impacts(sim.impacts)
            for slot, values in zip(slots, sent.get(stamp, ()), strict=False):
                slot.receive(values, stamp)
            held = [slot.held(stamp, timeout_ns)[0] for slot in slots]
            recorder.commands(stamp, *apply_commands(sim, *held, gains is not None))
            sim.advance_to(grid.time(k + 1))
    finally:
        recorder.close()


def test_a_node_bag_balances_energy_when_a_command_times_out(tmp_path):
    """The node publishes, at stamp k + 1, the efforts of the segment that ENDED there; plot
    takes the efforts over each interval from the recorded commands instead, so a command
    that times out leaves no phantom step in the balance (it was −2.2 J when each effort was
    applied one sample late in the issue's run, 0.75 J here). Re-simulation agrees with the
    bag bit for bit."""
    scene = load_scene()
    path = tmp_path / "node_bag"
    record_node_bag(path, scene, {10_000_000: ([1.0, 1.0], [4.8, 5.9, 0.0, 1.0])},
                    timeout_ns=700_000_000, duration=1.2)
    run = load_run(path)
    assert "/arm_effort_controller/commands" in run.effort_source
    balance = run.energy - run.energy[0] - work(run) + impact_losses(run)
    assert np.abs(balance).max() < 5e-3
    # The published efforts, held one sample late, are what made the phantom step.
    late = run.efforts.copy()
    run.efforts = np.vstack([late[:1] * 0, late[:-1]])
    shifted = run.energy - run.energy[0] - work(run) + impact_losses(run)
    assert np.abs(np.diff(shifted)).max() > 0.5   # a step of 0.75 J at the timeout
    result = subprocess.run([str(BIN / "replay"), str(path), "--resimulate"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "IDENTICAL" in result.stdout, result.stdout + result.stderr


def test_a_velocity_mode_bag_balances_energy_with_the_loops_torques(tmp_path):
    """cmd_vel in the bag, no wheel torques: the wheels take the speed loop's torques (from
    /joint_states and the jump of its proportional term at each cmd_vel change); with the
    default gains (2.0, 20.0) the balance stays within 0.1 J (77 mJ: the loop's transients after
    an impact are faster than the 100 Hz samples; 28 mJ with slower gains 0.5,
    5.0), and the bag re-simulates bit for bit."""
    scene = load_scene()
    path = tmp_path / "velocity_bag"
    record_node_bag(path, scene, {10_000_000: ([0.3, 0.5], [4.8, 5.9, 0.0, 1.0])},
                    timeout_ns=700_000_000, duration=1.2, gains=DEFAULT_WHEEL_SPEED_GAINS)
    run = load_run(path)
    assert run.effort_source == ("/joint_states wheel torques and "
                                 "/arm_effort_controller/commands")
    balance = run.energy - run.energy[0] - work(run) + impact_losses(run)
    assert np.abs(balance).max() < 1e-1
    result = subprocess.run([str(BIN / "replay"), str(path), "--resimulate"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "IDENTICAL" in result.stdout, result.stdout + result.stderr


@pytest.mark.parametrize("name", [r"$\frac{$", "$x$ and $", "50 $ a day", "^_{}%&#\\"])
def test_a_scene_name_that_matplotlib_would_read_as_mathtext_is_drawn_as_written(tmp_path, name):
    """A scene's name reaches the figures' titles: `$\\frac{$` once failed the whole plot with
    mathtext's parse error. Each title that names the scene shows its text, every `$` kept."""
    scene = parse_scene({**load_scene().document, "name": name}, "scene")
    assert scene.name == name
    write_bag(tmp_path / "bag", scene, 0.05)
    figures = plot(tmp_path / "bag", tmp_path / "figures")
    for figure in figures.values():
        figure.canvas.draw()   # mathtext parses here
        title = figure.get_suptitle() if hasattr(figure, "get_suptitle") else \
            figure._suptitle.get_text()
        assert title.replace("\\$", "$").startswith(f"{name}: ")
    assert sorted(p.name for p in (tmp_path / "figures").glob("*.png")) == \
        sorted(f"{n}.png" for n in FIGURE_NAMES)


def test_a_bags_topic_names_are_shown_escaped_never_raw(tmp_path, capsys):
    """Topic names come from the bag: an escape sequence would recolour the terminal, a
    newline forge a line of its own. The refusal shows them escaped, in its one line."""
    bag_path = tmp_path / "hostile"
    with BagWriter(bag_path) as bag:
        for topic in ("/odom\x1b[31m", "/fake\nplot: wrote 9 figures", "/clock"):
            bag.add_topic(topic, "rosgraph_msgs/msg/Clock", qos_yaml())
            bag.write(topic, serialize_message(Clock()), 0)
    status = plot_cli.main([str(bag_path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == EXIT_USER_ERROR, err
    assert err.count("\n") == 1 and "\x1b" not in err and "no /joint_states topic" in err, err
    assert r"'/odom\x1b[31m'" in err and r"'/fake\nplot: wrote 9 figures'" in err, err
