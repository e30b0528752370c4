"""The browser view: a local web page (PyPI ``viser``: a three.js scene served with its client,
scripts and assets from the installed package — the page asks nothing of any other host) that
draws the robot from its URDF (`drawing.read_urdf`) and moves it with /tf-shaped transforms
(`frames.Transform`, parent → child), beside the energy T + V and the end-stop impacts.

- `BrowserView`: the server, the robot, the energy plot and the impacts list; ``pose`` moves
  the links, ``status`` updates the figures. With "follow the robot" (on at first) the world
  slides under the robot so that its root stays where it started, in the camera's view; the
  robot still turns and its arm moves. Host loopback unless given (as the Foxglove view);
  a port in use is a one-line error (viser itself would quietly take the next one).
- `LiveBrowser`: `simulate --view browser` and the node — each sample drawn when the wall clock
  reaches it (the run paced to real time, `pacing.Pacer`), at most FRAME_RATE frames a second.
- `Player`: a recorded run (`recorded.Recording`: a CSV or a bag) with a time slider, play /
  pause and a speed, at FRAME_RATE.

Every link's transform comes from `frames.FrameTree` (runs of ours) or the bag's /tf: the view
computes no kinematics. `close` never waits on a browser: viser's stop runs in a thread of its
own, waited for CLOSE_WAIT s at most.
"""
from __future__ import annotations

import contextlib
import io
import socket
import threading
import time

import numpy as np

from ..ros.frames import ODOM, FrameTree
from ..runtime.pacing import Pacer
from ..runtime.timeline import NS, Grid
from ..scene.errors import UserError
from .drawing import Drawing

DEFAULT_PORT = 8080
DEFAULT_HOST = "127.0.0.1"   # loopback; "0.0.0.0" serves every interface
FRAME_RATE = 30.0            # frames a second sent to the browser
PLOT_PERIOD = 0.5            # s of wall time between redraws of the live energy plot
PLOT_POINTS = 3000           # the live energy plot's last points
CLOSE_WAIT = 1.0             # s: the longest `close` waits for the server to stop
SPEEDS = ("0.1", "0.25", "0.5", "1", "2", "4")
STROKE_RGB = (40, 120, 220)  # the strokes' segments and end marks
STOP_RADIUS = 0.03           # m, the end marks' radius (the stops)
FOV = 0.8                    # rad, the camera's vertical field of view
WORLD = "/world"             # the scene-graph frame the robot hangs from
GROUND = 30.0                # m, the side of the ground's grid


def camera(drawing: Drawing, focus) -> tuple[np.ndarray, np.ndarray]:
    """(position, look-at point) of the first camera: looking at ``focus`` (the root's world
    position) from the front right, above, as far back as the robot is large."""
    extent = drawing.extent()
    look_at = np.array([focus[0], focus[1], 0.15 * extent])
    return look_at + extent * np.array([0.65, -1.0, 0.7]), look_at


def _rgb(rgba) -> tuple:
    return tuple(int(round(255 * min(max(c, 0.0), 1.0))) for c in rgba[:3])


class BrowserView:
    """A viser server on ``host:port`` (0: any free port) drawing ``drawing``, the camera on
    ``focus`` (x, y of the robot's start). ``port_key`` names the setting in errors."""

    def __init__(self, drawing: Drawing, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST,
                 focus=(0.0, 0.0), port_key: str = "port", title: str = "mobile_manip_sim"):
        try:
            import viser
        except ImportError:
            raise UserError("browser view", "the Python package viser is not installed (pip "
                                            "install viser)") from None
        # the live view's own check, imported here as the adapters import it (it loads rclpy)
        from ..ros.live_view import check_port
        check_port(port, port_key)
        self.host = host
        if port and _in_use(host, port):
            raise UserError(f"{port_key} {port}", f"cannot serve the browser view on {host}: "
                                                  f"the port is in use")
        try:   # viser prints a banner on stdout, which belongs to the run's own lines
            with contextlib.redirect_stdout(io.StringIO()):
                self.server = viser.ViserServer(host=host, port=port, label=title,
                                                verbose=False)
        except (OSError, ValueError) as error:
            raise UserError(f"{port_key} {port}", f"cannot serve the browser view on {host} "
                                                  f"({error})") from None
        self.port = self.server.get_port()
        self.drawing = drawing
        self._lock = threading.Lock()
        self._draw_robot(focus)
        self._gui()

    @property
    def url(self) -> str:
        host = "localhost" if self.host in ("127.0.0.1", "::1", "localhost") else (
            socket.gethostname() if self.host in ("0.0.0.0", "::") else self.host)
        return f"http://{host}:{self.port}/"

    def _draw_robot(self, focus) -> None:
        scene, drawing = self.server.scene, self.drawing
        scene.set_up_direction("+z")
        # No image-based lighting and no shadows: a page's first frame costs seconds less on a
        # machine that draws WebGL on the CPU (software rendering), and the robot reads as well
        scene.configure_environment_map(hdri=None)
        scene.configure_default_lights(enabled=True, cast_shadow=False)
        scene.world_axes.visible = False
        self.focus = np.array([focus[0], focus[1], 0.0])
        self.world = scene.add_frame(WORLD, show_axes=False)   # slid by "follow the robot"
        self.ground = scene.add_grid("/ground", width=GROUND, height=GROUND, cell_size=0.25,
                                     section_size=1.0, position=(focus[0], focus[1], -0.001))
        position, look_at = camera(drawing, focus)
        self.server.initial_camera.position = position
        self.server.initial_camera.look_at = look_at
        self.server.initial_camera.up = (0.0, 0.0, 1.0)
        self.server.initial_camera.fov = FOV
        self.links, self._poses = {}, {}
        for link in [drawing.root, *drawing.parent]:
            path = WORLD + drawing.path(link)
            self.links[link] = scene.add_frame(path, show_axes=False)
            for i, shape in enumerate(drawing.visuals.get(link, ())):
                name, place = f"{path}/shape_{i}", {"position": shape.xyz, "wxyz": shape.wxyz}
                if shape.kind == "box":
                    scene.add_box(name, color=_rgb(shape.rgba), dimensions=shape.size, **place)
                elif shape.kind == "cylinder":
                    scene.add_cylinder(name, radius=shape.size[0], height=shape.size[1],
                                       color=_rgb(shape.rgba), **place)
                else:
                    scene.add_icosphere(name, radius=shape.size[0], color=_rgb(shape.rgba),
                                        **place)
        for stroke in drawing.strokes:   # drawn in the parent: they stay while the rod slides
            path = f"{WORLD}{drawing.path(stroke.parent)}/stroke_{stroke.joint.replace('/', '|')}"
            # beside the rod (which runs along it): a rail its thickness away, along z
            thickness = max((max(v.size) if v.kind == "sphere" else v.size[0]
                             for v in drawing.visuals.get(stroke.child, ())
                             if v.kind != "box"), default=0.0)
            scene.add_frame(path, show_axes=False, position=(0.0, 0.0, 2.0 * thickness))
            scene.add_line_segments(f"{path}/rail", points=np.array([[stroke.lower,
                                                                      stroke.upper]]),
                                    colors=STROKE_RGB, line_width=4.0)
            for end, point in (("lower", stroke.lower), ("upper", stroke.upper)):
                scene.add_icosphere(f"{path}/{end}", radius=STOP_RADIUS, color=STROKE_RGB,
                                    position=point)

    def _gui(self) -> None:
        gui = self.server.gui
        self.follow = gui.add_checkbox("follow the robot", initial_value=True)
        self.follow.on_update(lambda _: self._slide(self._root))
        self._root = self.focus
        self.time = gui.add_number("t (s)", initial_value=0.0, disabled=True, step=0.001)
        self.energy = gui.add_number("T + V (J)", initial_value=0.0, disabled=True, step=1e-6)
        self.plot = gui.add_uplot(data=(np.zeros(2), np.zeros(2)),
                                  series=({"label": "t (s)"},
                                          {"label": "T + V (J)", "stroke": "#2060c0",
                                           "width": 2}),
                                  scales={"x": {"time": False}}, title="energy T + V (J)",
                                  aspect=1.6)
        self.impacts = gui.add_markdown("**impacts**: none yet")
        self._shown_impacts = 0

    def pose(self, transforms) -> None:
        """Move the links: each `frames.Transform` parent → child sets the child's pose in its
        parent (the root's: in the world, whatever its parent is called). Transforms of frames
        the URDF does not have, or with another parent than the URDF's, are left out."""
        parent = self.drawing.parent
        with self._lock, self.server.atomic():
            for transform in transforms:
                child = transform.child
                handle = self.links.get(child)
                if handle is None or (child in parent and parent[child] != transform.parent):
                    continue
                # only what changed goes out (a slide keeps its rotation, a turn its origin)
                last = self._poses.get(child)
                if last is None or last[0] != transform.translation:
                    handle.position = transform.translation
                if last is None or last[1] != transform.rotation:
                    x, y, z, w = transform.rotation
                    handle.wxyz = (w, x, y, z)
                self._poses[child] = (transform.translation, transform.rotation)
                if child == self.drawing.root:
                    self._slide(np.array([*transform.translation[:2], 0.0]))

    def _slide(self, root) -> None:
        """Follow the robot: the world moves by where its root went since the start."""
        self._root = root
        offset = self.focus - root if self.follow.value else np.zeros(3)
        self.world.position = offset
        # the ground slides by as much modulo its 1 m sections: it never runs out
        self.ground.position = self.focus + np.mod(offset, 1.0) - (0.0, 0.0, 0.001)

    def status(self, t: float, energy: float | None, impacts: list) -> None:
        """The time, T + V (J; None: unknown) and the impacts up to now (dicts with time,
        link, stop, energy_lost, or `impact_log.Impact`; only a changed count is redrawn)."""
        with self._lock:
            self.time.value = round(t, 6)
            if energy is not None:
                self.energy.value = float(energy)
            if len(impacts) != self._shown_impacts:
                self._shown_impacts = len(impacts)
                last = [i if isinstance(i, dict) else i.as_dict() for i in impacts[-8:]]
                lines = [f"- t = {i['time']:.4f} s: rod {i['link']} at its {i['stop']} stop, "
                         f"{i['energy_lost']:.3g} J lost" for i in last]
                self.impacts.content = (f"**impacts**: {len(impacts)}\n\n" + "\n".join(lines)
                                        if impacts else "**impacts**: none yet")

    def plot_energy(self, t, energy) -> None:
        if len(t) >= 2:
            with self._lock:
                self.plot.data = (np.asarray(t, dtype=float), np.asarray(energy, dtype=float))

    def close(self) -> None:
        """Stop the server, waiting CLOSE_WAIT s at most (a browser never holds a stop up)."""
        server, self.server = getattr(self, "server", None), None
        if server is None:
            return

        def stop():
            with contextlib.redirect_stdout(io.StringIO()):
                server.stop()

        stopper = threading.Thread(target=stop, name="browser view stop", daemon=True)
        stopper.start()
        stopper.join(CLOSE_WAIT)


def _in_use(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError:
            return True
    return False


class LiveBrowser:
    """A run seen live: `simulate --view browser` calls ``sample(sim)`` at every sample (paced
    to real time: each waits for the wall clock), the node ``show(sim, stamp)`` at every
    publication (``paced`` False: it paces itself). A frame goes to the browser at most
    FRAME_RATE times a second, and always for the run's last sample (`finish`). A stamp
    earlier than the last (the node's reset) starts the energy plot again."""

    def __init__(self, scene, drawing: Drawing, port: int, host: str = DEFAULT_HOST,
                 sample_rate: float = 100.0, duration: float | None = None,
                 paced: bool = True, port_key: str = "port", tree: FrameTree | None = None,
                 odom: str = ODOM):
        self.tree = tree or FrameTree(scene.robot)
        self.odom = odom
        self.view = BrowserView(drawing, port, host, focus=scene.initial_q[:2],
                                port_key=port_key)
        self.url = self.view.url
        q0 = scene.initial_q   # drawn at once: a page opened before the first sample shows it
        self.view.pose(self.tree.static_transforms() + [self.tree.base_transform(q0, odom)]
                       + self.tree.moving_transforms(q0))
        self.grid = Grid(sample_rate, duration)
        self.pacer = Pacer(1.0, 1.0 / sample_rate) if paced else None
        self._k = 0
        self._drawn = -np.inf        # wall time of the last frame sent
        self._plotted = -np.inf
        self._t, self._energy = [], []
        self._last = None

    def sample(self, sim) -> None:
        k, stamp = self._k, self.grid.stamp(self._k)
        self._k += 1
        if self.pacer is not None:
            self.pacer.wait_for(stamp, first=k == 0)
        self.show(sim, stamp)

    def show(self, sim, stamp: int) -> None:
        """The state ``sim`` at ``stamp`` ns: drawn when a frame is due."""
        energy = float(sum(sim.dynamics.energy(sim.q, sim.u)))   # T + V
        first = not self._t or stamp / NS < self._t[-1]
        if first:
            self._t, self._energy, self._plotted = [], [], -np.inf
        self._t.append(stamp / NS)
        self._energy.append(energy)
        now = time.monotonic()
        if now - self._drawn >= 1.0 / FRAME_RATE or first:
            self._draw(sim, stamp, energy, now)
            self._last = None
        else:
            self._last = (sim.q.copy(), stamp, energy, _impacts(sim))

    def _draw(self, sim, stamp: int, energy: float, now: float) -> None:
        self._drawn = now
        q = sim.q
        self.view.pose([self.tree.base_transform(q, self.odom)]
                       + self.tree.moving_transforms(q))
        self.view.status(stamp / NS, energy, _impacts(sim))
        if now - self._plotted >= PLOT_PERIOD:
            self._plotted = now
            self.view.plot_energy(self._t[-PLOT_POINTS:], self._energy[-PLOT_POINTS:])

    def finish(self) -> None:
        """The last sample drawn (the run ended between frames), and the whole energy plot."""
        if self._last is not None:
            q, stamp, energy, impacts = self._last
            self.view.pose([self.tree.base_transform(q, self.odom)]
                           + self.tree.moving_transforms(q))
            self.view.status(stamp / NS, energy, impacts)
            self._last = None
        self.view.plot_energy(self._t[-PLOT_POINTS:], self._energy[-PLOT_POINTS:])

    def close(self) -> None:
        self.view.close()


def _impacts(sim):
    return getattr(sim, "impacts", ())   # the engine's list (no copy: read only)


class Player:
    """A recorded run (`recorded.Recording`) in the browser: a time slider, play / pause, a
    speed; playing from the start at speed 1 when the page opens, and looping."""

    def __init__(self, recording, port: int, host: str = DEFAULT_HOST,
                 port_key: str = "port"):
        self.recording = recording
        self.view = BrowserView(recording.drawing, port, host, focus=recording.focus,
                                port_key=port_key)
        self.url = self.view.url
        self.view.pose(recording.static)
        t = recording.t
        if recording.energy is not None:
            self.view.plot_energy(t, recording.energy)
        gui = self.view.server.gui
        step = float(np.min(np.diff(t))) if len(t) > 1 else 0.01
        self.slider = gui.add_slider("time (s)", min=float(t[0]), max=float(max(t[-1], t[0]
                                     + step)), step=step, initial_value=float(t[0]))
        self.playing = gui.add_checkbox("play", initial_value=True)
        self.speed = gui.add_dropdown("speed", options=SPEEDS, initial_value="1")
        self._shown = -1
        self._stop = threading.Event()
        self.show(0)
        self.slider.on_update(lambda _: self.show(self.index(self.slider.value)))
        self._thread = threading.Thread(target=self._play, name="browser player", daemon=True)
        self._thread.start()

    def index(self, t: float) -> int:
        """The last sample at or before ``t`` s."""
        return max(0, int(np.searchsorted(self.recording.t, t, side="right")) - 1)

    def show(self, k: int) -> None:
        if k == self._shown:
            return
        self._shown = k
        recording = self.recording
        self.view.pose(recording.frames[k])
        t = float(recording.t[k])
        self.view.status(t, None if recording.energy is None else recording.energy[k],
                         [i for i in recording.impacts if i["time"] <= t])

    def _play(self) -> None:
        t = self.recording.t
        last = time.monotonic()
        while not self._stop.wait(1.0 / FRAME_RATE):
            now = time.monotonic()
            if self.playing.value:
                advanced = self.slider.value + (now - last) * float(self.speed.value)
                if advanced > t[-1]:
                    advanced = float(t[0])   # loop
                self.slider.value = advanced
                self.show(self.index(advanced))
            last = now

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.view.close()
