"""The robots through bitcraze's cflib: one ``CfRobot`` per Crazyflie of the swarm file.

What the mission (ground/mission.py) asks of a robot, done with cflib's own calls:
parameters by name (``cf.param``), the trajectory memory (``cf.mem``, the
``TYPE_TRAJ`` element: its size is read from the robot at connect, never
assumed), the high-level commander (``cf.high_level_commander``), log blocks
(``cf.log``), and the link (``cf.link_statistics``).  cflib's ``Swarm`` opens the
links.  No radio is needed to import this module: the tests connect it to a
link driver of their own (tests/cfrobot.py).
"""
from __future__ import annotations

import threading

from ns2codegen.errors import Ns2Error
from ns2plan.output import POLY4D_BYTES, read_poly4d

# log blocks: each fits a CRTP log packet (26 bytes of data); every name is checked
# against the built cf2.elf's LOG table (tests/test_ground_cf.py).  With the state,
# the attitude, the motor PWM and the battery the radio log is a labelled data set
# (ns2 logs-to-data, ns2codegen/logs/radiolog.py)
LOG_BLOCKS = (
    ("ns2a", ("ns2.faHat", "ns2.status", "ns2.ex", "ns2.ey", "ns2.ez", "pm.vbat")),
    ("ns2b", ("stateEstimate.x", "stateEstimate.y", "stateEstimate.z", "stateEstimate.vx", "stateEstimate.vy",
              "ns2.nUsed")),
    ("ns2c", ("stateEstimate.vz", "ns2.inferUs", "ns2.ctrlStatus", "pm.state", "motor.m1", "motor.m2", "motor.m3",
              "motor.m4")),
    ("ns2d", ("stateEstimate.qw", "stateEstimate.qx", "stateEstimate.qy", "stateEstimate.qz")),
    # the on-board adaptation (docs/adaptation.md): theta, trace of P, the on-board label, statuses
    ("ns2e", ("ns2adapt.bias", "ns2adapt.scale", "ns2adapt.trP", "ns2adapt.label", "ns2adapt.status",
              "ns2adapt.lstatus")),
)
LOG_PERIOD_MS = 50
TRAJECTORY_ID = 1
# the high-level commander's group of the ns2 swarm: every robot joins it before take-off,
# and take-off and the trajectory start address it (the firmware's isInGroup), so the
# same command can go to the whole swarm in one radio broadcast; land and stop go to
# every group (ALL_GROUPS): nothing may keep a robot from landing
GROUP = 0x80


class LinkError(Ns2Error, RuntimeError):
    """A robot does not answer or refuses a command."""


class CfRobot:
    """One Crazyflie, through an open cflib ``SyncCrazyflie``."""

    def __init__(self, name: str, scf):
        self.name, self.scf, self.cf = name, scf, scf.cf
        self.lost = threading.Event()
        self.cf.disconnected.add_callback(lambda uri: self.lost.set())
        self.cf.connection_lost.add_callback(lambda uri, msg: self.lost.set())
        self._logs = []
        self.quality = float("nan")     # link quality (%), from cflib's link statistics
        self.cf.link_statistics.link_quality_updated.add_callback(self._quality)

    def _quality(self, percent) -> None:
        self.quality = float(percent)

    # -- parameters
    def param(self, full: str):
        group, name = full.split(".")
        el = self.cf.param.toc.get_element(group, name)
        if el is None:
            return None
        return self.cf.param.get_value(full)

    def has_param(self, full: str) -> bool:
        group, name = full.split(".")
        return self.cf.param.toc.get_element(group, name) is not None

    def set_param(self, full: str, value, timeout_s: float = 5.0) -> None:
        """Write a parameter and wait until the robot confirms it (the firmware echoes a
        write once the value is in place and its callback ran): cflib only queues the
        write, and a command sent after it could otherwise arrive first."""
        if not self.has_param(full):
            raise LinkError(f"{self.name}: no parameter {full} on the robot")
        group, name = full.split(".")
        done = threading.Event()

        def confirmed(_name, _value):
            done.set()

        self.cf.param.add_update_callback(group=group, name=name, cb=confirmed)
        try:
            self.cf.param.set_value(full, value)
            if not done.wait(timeout_s):
                raise LinkError(f"{self.name}: {full}: the robot did not confirm the write within {timeout_s:g} s")
        finally:
            self.cf.param.remove_update_callback(group=group, name=name, cb=confirmed)

    # -- trajectory memory and high-level commander
    def trajectory_memory_size(self) -> int:
        from cflib.crazyflie.mem import MemoryElement

        mems = self.cf.mem.get_mems(MemoryElement.TYPE_TRAJ)
        if not mems:
            raise LinkError(f"{self.name}: no trajectory memory (the high-level commander is not in the firmware)")
        return int(mems[0].size)

    def upload(self, data: bytes) -> int:
        """Write poly4d pieces (planner/output.py's bytes) from address 0; returns the piece count."""
        from cflib.crazyflie.mem import MemoryElement
        from cflib.crazyflie.mem.trajectory_memory import Poly4D

        size = self.trajectory_memory_size()
        if len(data) > size:
            raise LinkError(f"{self.name}: the plan needs {len(data)} bytes ({len(data) // POLY4D_BYTES} pieces), "
                            f"the robot's trajectory memory holds {size}")
        mem = self.cf.mem.get_mems(MemoryElement.TYPE_TRAJ)[0]
        mem.trajectory = [Poly4D(d, *(Poly4D.Poly([float(x) for x in c[a]]) for a in range(4)))
                          for d, c in read_poly4d(data)]
        if not mem.write_data_sync():
            raise LinkError(f"{self.name}: the trajectory upload failed")
        n = len(data) // POLY4D_BYTES
        self.cf.high_level_commander.define_trajectory(TRAJECTORY_ID, 0, n)
        if self.has_param("hlCommander.groupmask"):   # the command is deprecated for this parameter
            self.set_param("hlCommander.groupmask", GROUP)
        else:
            self.cf.high_level_commander.set_group_mask(GROUP)
        return n

    def takeoff(self, height: float, duration: float) -> None:
        self.cf.high_level_commander.takeoff(height, duration, group_mask=GROUP)

    def start(self) -> None:
        self.cf.high_level_commander.start_trajectory(TRAJECTORY_ID, 1.0, False, group_mask=GROUP)

    def land(self, duration: float) -> None:
        self.cf.high_level_commander.land(0.0, duration)

    def stop(self) -> None:
        self.cf.high_level_commander.stop()

    # -- logs
    def start_logs(self, callback) -> None:
        """``callback(name, timestamp_ms, {variable: value})`` for every log packet."""
        from cflib.crazyflie.log import LogConfig

        for block, names in LOG_BLOCKS:
            lc = LogConfig(name=block, period_in_ms=LOG_PERIOD_MS)
            for n in names:
                lc.add_variable(n)
            self.cf.log.add_config(lc)
            if not lc.valid:
                raise LinkError(f"{self.name}: log block {block} is not valid on the robot ({', '.join(names)})")
            lc.data_received_cb.add_callback(lambda ts, data, conf, n=self.name: callback(n, ts, data))
            lc.start()
            self._logs.append(lc)


def open_swarm(uris: dict[str, str]):
    """cflib's ``Swarm`` over the robots' uris (name -> uri), links open; returns
    (swarm, {name: CfRobot}).  A robot that does not answer: one line naming it."""
    import cflib.crtp
    from cflib.crazyflie.swarm import CachedCfFactory, Swarm

    if not cflib.crtp.CLASSES:
        cflib.crtp.init_drivers()
    swarm = Swarm(list(uris.values()), factory=CachedCfFactory(rw_cache=None))
    try:
        swarm.open_links()
    except Exception as e:  # cflib raises Exception('Failed to connect to ...')
        by_uri = {u: n for n, u in uris.items()}
        who = next((n for u, n in by_uri.items() if u in str(e)), "a robot")
        raise LinkError(f"{who}: does not answer ({' '.join(str(e).split())}); see docs/flying.md") from e
    return swarm, {n: CfRobot(n, swarm._cfs[u]) for n, u in uris.items()}

