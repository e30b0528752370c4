"""The browser view (view/browser.py) as a user sees it: `simulate --view browser` and
`replay RUN --view browser` in their own processes, and a real headless chromium
(headless_browser.py) loading the page. For each source — a live run, a CSV, a bag of ours, a
bag of another program (/tf, /tf_static and /robot_description only) — two
screenshots show the robot (pixels of its rods' colour inside the box the robot's links project
to, through the page's camera) and show that it moved between them; the page asked nothing of
any host but its own; SIGINT ends the process at once, the run's CSV complete.

``BROWSER_VIEW_FIGURE=docs/figures/browser_view.png`` keeps the live test's screenshot (the
README's figure)."""
import csv
import itertools
import os
import signal
import subprocess
import threading
from urllib.parse import urlsplit

import numpy as np
import pytest
from PIL import Image

from bag_rewrite import rewrite_bag
from executables import executable
from headless_browser import HEIGHT, WIDTH, Browser
from mobile_manip_sim.recording.bag_reader import open_bag
from mobile_manip_sim.ros.frames import FrameTree
from mobile_manip_sim.ros.urdf import robot_description
from mobile_manip_sim.runtime.headless import csv_columns
from mobile_manip_sim.scene.coordinates import ARM_Q, YAW
from mobile_manip_sim.scene.loading import load_scene
from mobile_manip_sim.view.browser import FOV, camera
from mobile_manip_sim.view.drawing import read_urdf
from waiting import wait_for

SIMULATE, REPLAY = executable("simulate"), executable("replay")
TIMEOUT = 120.0      # s: a loaded machine's first page (SwiftShader draws on the CPU)
ROD = (217, 115, 25)   # urdf.py's rod colour, lit
MARGIN = 40          # px around the projected links (the rods' and the chassis' thickness)
# Mantine's notifications (viser's "software WebGL" note is orange like the rods): hidden
HIDE_NOTES = ("document.addEventListener('DOMContentLoaded', () => document.head.insertAdjacent"
              "HTML('beforeend', '<style>.mantine-Notifications-root{display:none!important}"
              "</style>'))")


def start(*args) -> tuple[subprocess.Popen, str]:
    """A view process; (process, the page's URL from its first line)."""
    process = subprocess.Popen([*args, "--view-port", "0"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    timer = threading.Timer(TIMEOUT, process.kill)   # bounds the wait for the first line
    timer.start()
    try:
        first = process.stdout.readline()
    finally:
        timer.cancel()
    assert first.startswith("view: http://localhost:"), first + process.stderr.read()
    return process, first.split()[1]


def rod_pixels(image: np.ndarray) -> np.ndarray:
    """Where the picture has the rods' orange (hue ~28°, saturated; any shade the lights give
    it)."""
    r, g, b = (image[..., i].astype(float) for i in range(3))
    top, bottom = np.maximum(np.maximum(r, g), b), np.minimum(np.minimum(r, g), b)
    spread = np.maximum(top - bottom, 1.0)
    hue = 60.0 * (g - b) / spread   # where red is the largest
    return (r == top) & (top > 80) & (spread > 0.55 * top) & (hue > 12) & (hue < 45)


def world_points(scene, q_rows) -> np.ndarray:
    """Every link frame's origin, and each rod's far end, at each configuration where the page
    draws it: composed here from the tree's transforms (quaternions as numpy rotations), less
    how far the base went from the scene's start (the page follows the robot)."""
    tree = FrameTree(scene.robot)
    points = []
    start = np.array([*scene.initial_q[:2], 0.0])
    # a rod's frame is at its distal end; the rod reaches L back from it (urdf.py)
    ends = {f"arm_rod_{k + 1}": np.array([-length, 0.0, 0.0])
            for k, length in enumerate(scene.robot.length)}
    for q in q_rows:
        slide = np.array([q[0], q[1], 0.0]) - start
        poses = {}
        for transform in ([tree.base_transform(q)] + tree.static_transforms()
                          + tree.moving_transforms(q)):
            poses[transform.child] = (transform.parent, transform)
        for child, tail in [(c, np.zeros(3)) for c in poses] + list(ends.items()):
            p, link = tail, child
            while link in poses:
                parent, transform = poses[link]
                x, y, z, w = transform.rotation
                rotation = np.array([
                    [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
                p = rotation @ p + np.array(transform.translation)
                link = parent
            points.append(p - slide)
    return np.array(points)


def reach(scene) -> list:
    """Configurations at the start's base position over every yaw, joint angle and both ends
    of every stroke: where the robot can be drawn while the page follows it."""
    model, q0 = scene.robot, np.array(scene.initial_q, dtype=float)
    rows = []
    angles = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    axes = [np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    for k in range(model.n_links):
        axes += [angles, np.array(model.stroke[k], dtype=float)]
    for values in itertools.product(*axes):
        q = q0.copy()
        q[YAW], q[ARM_Q] = values[0], values[1:]
        rows.append(q)
    return rows


def projected_box(scene, q_rows) -> tuple[int, int, int, int]:
    """(left, top, right, bottom) px of the robot's links over ``q_rows``, through the page's
    first camera (a three.js perspective camera: vertical field of view FOV, +z up)."""
    position, look_at = camera(read_urdf(robot_description(scene)), scene.initial_q[:2])
    forward = (look_at - position) / np.linalg.norm(look_at - position)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    d = world_points(scene, q_rows) - position
    depth = d @ forward
    assert np.all(depth > 0), "the robot is behind the camera"
    half = np.tan(FOV / 2)
    x = (d @ right) / (depth * half * WIDTH / HEIGHT)
    y = (d @ up) / (depth * half)
    u, v = (x + 1) / 2 * WIDTH, (1 - y) / 2 * HEIGHT
    return (int(u.min()) - MARGIN, int(v.min()) - MARGIN, int(u.max()) + MARGIN,
            int(v.max()) + MARGIN)


def robot_in(image, box) -> np.ndarray:
    """The rods' pixels inside ``box`` (a mask the size of the box)."""
    left, top, right, bottom = box
    return rod_pixels(image[max(top, 0):bottom, max(left, 0):right])


def two_instants(browser: Browser, url: str, box) -> tuple[np.ndarray, np.ndarray]:
    """Open the page; the first screenshot that shows the robot inside ``box``, then the first
    one after it where the robot's pixels moved (both: a test failure when they never come)."""
    browser.call("Page.addScriptToEvaluateOnNewDocument", source=HIDE_NOTES)
    browser.open(url)
    first = wait_for(lambda: (lambda image: image if robot_in(image, box).sum() >= 30 else None)(
        browser.screenshot()), "the robot drawn in the page", TIMEOUT)
    before = robot_in(first, box)

    def moved():
        image = browser.screenshot()
        after = robot_in(image, box)
        changed = (before ^ after).sum()
        return image if after.sum() >= 30 and changed > 0.3 * before.sum() else None

    return first, wait_for(moved, "the robot moving in the page", TIMEOUT)


def requests_by_host(browser: Browser, url: str) -> tuple[list, list]:
    """(the page's requests outside its host, its websocket requests), from the network log."""
    host = urlsplit(url).netloc
    outside = [u for u in browser.requests
               if urlsplit(u).scheme not in ("data", "blob") and urlsplit(u).netloc != host]
    return outside, [u for u in browser.requests if urlsplit(u).scheme == "ws"]


def moved_pixels(first: np.ndarray, second: np.ndarray, box) -> tuple[int, int, int]:
    """(robot pixels in ``box`` in the first screenshot, in the second, pixels that changed)."""
    before, after = robot_in(first, box), robot_in(second, box)
    return int(before.sum()), int(after.sum()), int((before ^ after).sum())


def stop(process: subprocess.Popen, status: int) -> None:
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=15)   # at once: not at a browser's leisure
    assert process.returncode == status, err


def csv_rows(path) -> np.ndarray:
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == csv_columns(load_scene().robot.n_links)
    return np.array(rows[1:], dtype=float)


def test_a_live_run_moves_in_the_browser(tmp_path):
    out = tmp_path / "run.csv"
    process, url = start(SIMULATE, "--view", "browser", "--duration", "600", "--out", str(out))
    scene = load_scene()
    try:
        with Browser() as browser:
            # where the robot goes is known once the run's CSV is: where it can reach till then
            first, second = two_instants(browser, url, projected_box(scene, reach(scene)))
            outside, sockets = requests_by_host(browser, url)
    finally:
        stop(process, 130)
    assert outside == [] and sockets, (outside, sockets)
    rows = csv_rows(out)   # complete rows, every one, up to where SIGINT stopped the run
    assert len(rows) >= 2 and np.allclose(np.diff(rows[:, 0]), 0.01)
    q_rows = rows[:, 1:1 + scene.robot.n_q]
    box = projected_box(scene, q_rows)
    for name, image in (("first", first), ("second", second)):
        Image.fromarray(image).save(tmp_path / f"{name}.png")   # to look at when this fails
        assert robot_in(image, box).sum() >= 30, tmp_path
        outside = rod_pixels(image).sum() - robot_in(image, box).sum()
        assert outside < 0.05 * rod_pixels(image).sum(), f"robot pixels outside {box}: {tmp_path}"
    figure = os.environ.get("BROWSER_VIEW_FIGURE")
    if figure:
        Image.fromarray(second).save(figure)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A 1.5 s run of the paper scene, as a CSV, as a bag, and as a bag of another program
    (the same messages without our attachments: no scene, no impacts)."""
    where = tmp_path_factory.mktemp("recorded")
    subprocess.run([SIMULATE, "--record", str(where / "bag"), "--out", str(where / "run.csv")],
                   check=True, capture_output=True, timeout=600)
    rewrite_bag(where / "bag", where / "foreign",
                attachments={name: None for name in open_bag(where / "bag").attachments()})
    return where


@pytest.mark.parametrize("source", ["run.csv", "bag", "foreign"])
def test_a_recorded_run_plays_in_the_browser(recorded, source):
    scene = load_scene()
    box = projected_box(scene, csv_rows(recorded / "run.csv")[:, 1:1 + scene.robot.n_q])
    process, url = start(REPLAY, str(recorded / source), "--view", "browser")
    try:
        with Browser() as browser:
            first, second = two_instants(browser, url, box)
            outside, sockets = requests_by_host(browser, url)
    finally:
        stop(process, 0)   # a player serves until Ctrl-C: status 0
    before, after, changed = moved_pixels(first, second, box)
    assert before >= 30 and after >= 30 and changed > 0.3 * before, (before, after, changed)
    assert outside == [] and sockets, (outside, sockets)


@pytest.mark.parametrize("args, problem", [
    (["--view", "browser", "--view-port", "70000"], "--view-port: must be in [0, 65535]"),
    (["--view-port", "8080"], "--view-port: needs --view browser"),
    (["--view", "browsr"], "invalid int value: 'browsr'"),
    (["--view", "browser", "--view-host", "a b"], "--view-host: 'a b' is not a host name")])
def test_bad_browser_view_settings_are_one_line_errors(args, problem):
    result = subprocess.run([SIMULATE, *args, "--out", "/dev/null"], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and problem in lines[0], result.stderr


def test_a_browser_port_in_use_is_a_one_line_error(tmp_path):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run([SIMULATE, "--view", "browser", "--view-port", str(port),
                                 "--out", "/dev/null"], capture_output=True, text=True,
                                timeout=120)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"--view-port {port}" in lines[0] and "in use" in lines[0], \
        result.stderr
