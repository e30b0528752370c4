"""The node's recording (parameter `record`): its bags' run metadata, the commands as applied and
the states as published, one bag per time line (`recording.rotation.RotatingRecorder`). Only
the stepping thread calls it, outside the lock the services take (so a bag rotation never
delays a service), and the shutdown once that thread has stopped."""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable

from ..recording.arm_metadata import arm_controller_metadata
from ..recording.rotation import RotatingRecorder
from ..scene.errors import UserError
from ..scene.limits import RECORDING_BAGS

if TYPE_CHECKING:   # imported when a bag is opened: mcap and the CDR tables only when recording
    from ..recording.recorder import RunRecorder

BAG_FLUSH_INTERVAL = 1.0   # s of wall time: the most of a recording a SIGKILL may lose


class NodeRecording:
    """Records a run of ``sim`` (scene and integrator ``settings``) into new bags at ``path``;
    ``params`` is the node's `NodeParameters`. A path that cannot be used is a UserError
    naming `record`."""

    def __init__(self, path: str, sim, settings, params, info: Callable[[str], None],
                 error: Callable[[str], None]):
        self.sim, self._settings, self._params = sim, settings, params
        self._published: list[tuple[int, dict]] = []   # states not yet recorded
        try:
            self._bags = RotatingRecorder(path, self._open_bag, info, error,
                                          max_bags=RECORDING_BAGS)
        except UserError as failure:
            raise UserError("record", str(failure)) from None

    def _open_bag(self, path: str) -> RunRecorder:
        from ..recording.recorder import RunRecorder
        p = self._params
        metadata = {"source": "node", "publish_rate": repr(float(p.publish_rate)),
                    "controller_rate": repr(float(self.sim.control_rate)),
                    "base_command": p.base_command}
        if p.velocity_mode:
            metadata.update(wheel_speed_kp=repr(float(p.wheel_speed_gains[0])),
                            wheel_speed_ki=repr(float(p.wheel_speed_gains[1])))
        metadata.update(arm_controller_metadata(self.sim.arm_controller))
        metadata.update(p.imu_noise.as_metadata())
        return RunRecorder(path, self.sim.scene, self._settings, metadata,
                           flush_interval=BAG_FLUSH_INTERVAL, view=True, imu=True)

    def commands(self, start_ns: int, base, joints) -> None:
        """The commands held from the segment start ``start_ns`` on, as applied."""
        self._bags.commands(start_ns, base, joints)

    def arm_command(self, start_ns: int, message) -> None:
        """An arm controller's command applied from the segment start ``start_ns`` on."""
        self._bags.arm_command(start_ns, message)

    def published(self, stamp: int, messages: dict) -> None:
        """Under the loop's lock: state messages that went out, recorded by `record`."""
        self._published.append((stamp, messages))

    def record(self) -> None:
        """Record the states published since the last call. The engine is still at the last
        one's stamp, so its impact list is the run's up to there."""
        published, self._published = self._published, []
        for stamp, messages in published:
            self._bags.states(stamp, messages, self.sim.impacts)

    def flush(self) -> None:
        """A timer's: what is recorded goes to disk within BAG_FLUSH_INTERVAL, also while the
        node records nothing new (paused, failed)."""
        self._bags.flush()

    def close(self, info: Callable[[str], None], error: Callable[[str], None]) -> None:
        """After the stepping thread stopped: the bag gets its impacts, summary and
        metadata.yaml."""
        self.record()
        self._bags.close(info, error)
