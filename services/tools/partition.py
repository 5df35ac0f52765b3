"""``shepherd partition``: cut a real network link between the robot and the laptop (issue 20).

Two network namespaces joined by a veth pair: the robot's (``shepherd router --lease`` and
``deploy/sim-robot.toml``) and the laptop's (``deploy/sim-laptop.toml`` with the mission
``ahead_m`` in front of the humanoid). While the humanoid walks the link is cut for ``cut_s``,
healed, then flapped (``down_s`` down, ``up_s`` up), in one of three ways:

- ``down``: the laptop's end of the link goes down;
- ``drop``: packets silently dropped both ways (iptables INPUT on both sides);
- ``laptop``: the laptop alone falls off: its sends fail (iptables OUTPUT), the robot's vanish.

A probe in each namespace records arrivals on this host's monotonic clock (namespaces share
it, so ages are exact here; the services themselves never compare clocks). Needs root,
iproute2 and iptables (``scripts/install-test-deps``); :func:`unavailable` says why not.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

WAYS = ("down", "drop", "laptop")
ROOT = Path(__file__).resolve().parents[2]
PORT = 7447
LEASE_S = 1.5
STALE_S = 0.5  # the limit: no motion command older than this reaches the humanoid
#: the issue's goal for the first fresh pose on the laptop after a heal (s)
FRESH_GOAL_S = 5.0
#: what Zenoh lets us promise after a 5 s cut (s): the router closes a silently dropped link
#: with TCP's SO_LINGER of 10 s, which blocks its thread until the peer acknowledges or the
#: 10 s run out (eclipse-zenoh/zenoh#1101); until then it neither takes the client's new link
#: nor frees its id. The close starts at the lease's end (cut + 1.5-2 s) and a client's
#: attempt takes at most open_timeout_s + the retry period (3 s): 12 + 3 - 5 = 10 s, plus 1 s
#: for a loaded machine
FRESH_BOUND_S = 11.0


def _sh(*args: str, ns: str | None = None, check: bool = True) -> None:
    cmd = (["ip", "netns", "exec", ns] if ns else []) + list(args)
    subprocess.run(cmd, check=check, capture_output=True, text=True, timeout=20)


def unavailable() -> str:
    """Why network namespaces cannot be made here ('' when they can)."""
    if sys.platform != "linux":
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "making network namespaces needs root"
    for tool in ("ip", "iptables"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (scripts/install-test-deps installs it)"
    name = f"shep-probe-{os.getpid()}"
    try:
        _sh("ip", "netns", "add", name)
        _sh("iptables", "-L", "-n", ns=name)
    except (subprocess.CalledProcessError, OSError) as err:
        why = getattr(err, "stderr", "") or str(err)
        return f"cannot make a network namespace with iptables: {why.strip()}"
    finally:
        _sh("ip", "netns", "del", name, check=False)
    return ""


class Link:
    """Robot and laptop namespaces joined by a veth pair (``robot_ip`` <-> ``laptop_ip``)."""

    def __init__(self, tag: str = "") -> None:
        k = (os.getpid() % 200) + 20
        tag = tag or str(os.getpid())
        self.robot, self.laptop = f"shep-r{tag}", f"shep-l{tag}"
        self.robot_ip, self.laptop_ip = f"10.77.{k}.1", f"10.77.{k}.2"
        self._veth = (f"shr{tag}"[:15], f"shl{tag}"[:15])

    def __enter__(self) -> Link:
        r, lp = self._veth
        _sh("ip", "netns", "add", self.robot)
        _sh("ip", "netns", "add", self.laptop)
        _sh("ip", "link", "add", r, "netns", self.robot, "type", "veth", "peer", "name", lp,
            "netns", self.laptop)
        for ns, dev, ip in ((self.robot, r, self.robot_ip), (self.laptop, lp, self.laptop_ip)):
            _sh("ip", "addr", "add", f"{ip}/24", "dev", dev, ns=ns)
            _sh("ip", "link", "set", dev, "up", ns=ns)
            _sh("ip", "link", "set", "lo", "up", ns=ns)
        return self

    def __exit__(self, *exc: object) -> None:
        for ns in (self.robot, self.laptop):
            _sh("ip", "netns", "del", ns, check=False)

    def cut(self, way: str) -> None:
        self._apply(way, "-A")

    def heal(self, way: str) -> None:
        self._apply(way, "-D")

    def _apply(self, way: str, op: str) -> None:
        if way == "down":
            _sh("ip", "link", "set", self._veth[1], "down" if op == "-A" else "up",
                ns=self.laptop)
        elif way == "drop":
            _sh("iptables", op, "INPUT", "-s", self.laptop_ip, "-j", "DROP", ns=self.robot)
            _sh("iptables", op, "INPUT", "-s", self.robot_ip, "-j", "DROP", ns=self.laptop)
        elif way == "laptop":
            _sh("iptables", op, "OUTPUT", "-d", self.robot_ip, "-j", "DROP", ns=self.laptop)
            _sh("iptables", op, "INPUT", "-s", self.robot_ip, "-j", "DROP", ns=self.laptop)
        else:
            raise ValueError(f"unknown way {way!r}; expected one of {', '.join(WAYS)}")

    def spawn(self, ns: str, args: list[str], log: Path, cwd: Path, code: Path = ROOT
              ) -> subprocess.Popen[bytes]:
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(code)}
        with open(log, "wb") as out:
            return subprocess.Popen(["ip", "netns", "exec", ns, sys.executable, *args],
                                    stdout=out, stderr=subprocess.STDOUT, cwd=cwd, env=env,
                                    start_new_session=True)


# -- the probe (runs inside a namespace) ------------------------------------------------------

async def probe(connect: str, out: Path) -> None:
    """Record, with this host's monotonic arrival time: what reaches the humanoid (sim/ir),
    where it is (sim/truth), the poses, and the controller's liveliness token."""
    from schemas import HumanoidPose, IrCommand, Keys, SimTruth
    from schemas.keys import HUMANOID_POSE, IR_COMMAND, SIM_IR, SIM_TRUTH
    from services.runtime.bus import Bus
    from services.runtime.session import ZenohSettings, open_session
    settings = ZenohSettings(mode="client", connect=[connect], multicast_scouting=False,
                             lease_s=LEASE_S)
    with open_session(settings) as session, open(out, "w", buffering=1) as f:
        bus = Bus(session, Keys(), "probe")
        ir = bus.subscribe_stamped(SIM_IR, IrCommand, clock=time.monotonic_ns)
        decided = bus.subscribe_stamped(IR_COMMAND, IrCommand, clock=time.monotonic_ns)
        truth = bus.subscribe_stamped(SIM_TRUTH, SimTruth, clock=time.monotonic_ns)
        poses = bus.subscribe_stamped(HUMANOID_POSE, HumanoidPose, clock=time.monotonic_ns)
        alive = bus.subscribe_liveliness(bus.keys.alive("mission_controller"))
        def sent_s(c: IrCommand) -> float:
            """When the controller sent it, on the monotonic clock (from its Unix stamp for
            a controller that does not stamp sent_mono_ns: the namespaces share clocks)."""
            if c.sent_mono_ns is not None:
                return c.sent_mono_ns / 1e9
            return c.stamp_ns / 1e9 - (time.time() - time.monotonic())

        while True:
            for t, c in iter(ir.get_nowait, None):
                f.write(json.dumps({"k": "ir", "t": t / 1e9, "cmd": c.command.value,
                                    "sent": sent_s(c)}) + "\n")
            for t, c in iter(decided.get_nowait, None):
                f.write(json.dumps({"k": "cmd", "t": t / 1e9, "cmd": c.command.value,
                                    "sent": sent_s(c)}) + "\n")
            for _, s in iter(truth.get_nowait, None):
                # when the simulator stepped to this state (its Unix stamp, shared clock)
                when = s.stamp_ns / 1e9 - (time.time() - time.monotonic())
                f.write(json.dumps({"k": "truth", "t": when, "seq": s.seq, "x": s.humanoid.x,
                                    "y": s.humanoid.y}) + "\n")
            for t, p in iter(poses.get_nowait, None):
                f.write(json.dumps({"k": "pose", "t": t / 1e9,
                                    "lag": (time.time_ns() - p.stamp_ns) / 1e9}) + "\n")
            for _, up in iter(alive.get_nowait, None):
                f.write(json.dumps({"k": "alive", "t": time.monotonic(), "up": up}) + "\n")
            await asyncio.sleep(0.02)


# -- one run ----------------------------------------------------------------------------------

@dataclass
class Report:
    way: str
    cuts: list[tuple[float, float]] = field(default_factory=list)  # (cut, heal), monotonic s
    stop_after_cut_s: list[float] = field(default_factory=list)  # from the cut in effect
    cut_late_s: list[float] = field(default_factory=list)  # cut command start -> in effect
    token_gone_after_cut_s: list[float] = field(default_factory=list)
    stale_motion: list[float] = field(default_factory=list)  # ages (s) of late motion cmds
    motion_sent: int = 0
    oldest_motion_s: float = 0.0
    moved_late_m: list[float] = field(default_factory=list)  # moved > 1.5 s after last motion
    coast_m: list[float] = field(default_factory=list)
    still_after_last_motion_s: list[float] = field(default_factory=list)  # per cut
    sim_speed: float = 1.0  # simulated s per wall-clock s (below 1 when the CPU is short)
    fresh_pose_after_heal_s: list[float] = field(default_factory=list)
    completed: bool = False           # the controller reached the goal (the monitor's summary)
    final_error_cm: float | None = None  # by the simulator's truth
    done_after_last_heal_s: float | None = None
    restarts: int = 0
    memory_growth: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def failures(self) -> list[str]:
        """What breaks the issue's 'done when' (empty: all holds)."""
        out = []
        if self.stale_motion:
            out.append(f"{len(self.stale_motion)} motion commands older than {STALE_S} s "
                       f"reached the humanoid (oldest {max(self.stale_motion):.2f} s)")
        if any(d > 1.0 for d in self.stop_after_cut_s):
            out.append(f"stop later than 1 s after a cut: {self.stop_after_cut_s}")
        if self.moved_late_m:
            out.append(f"moved > 1.5 s after the last fresh motion command: {self.moved_late_m}")
        if len(self.fresh_pose_after_heal_s) < len(self.cuts) or any(
                d > FRESH_GOAL_S for d in self.fresh_pose_after_heal_s):
            out.append(f"fresh poses after heals: {self.fresh_pose_after_heal_s}")
        if not self.completed:
            out.append("the mission did not complete")
        if self.restarts:
            out.append(f"{self.restarts} restarts")
        if any(g > 0.20 for g in self.memory_growth.values()):
            out.append(f"memory growth {self.memory_growth}")
        return out


def _rss_kb(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _tree_rss_kb(pid: int) -> int:
    """RSS of a process and its children (the launcher's service processes)."""
    total = _rss_kb(pid)
    with contextlib.suppress(OSError):
        for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
            total += _tree_rss_kb(int(child))
    return total


def _records(path: Path) -> list[dict[str, object]]:
    out = []
    with contextlib.suppress(OSError):
        for line in path.read_text().splitlines():
            with contextlib.suppress(ValueError):
                out.append(json.loads(line))
    return out


def _wait_for(pred: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.1)
    raise TimeoutError(f"{what} not within {timeout:.0f} s")


@contextlib.contextmanager
def _stopping(procs: list[subprocess.Popen[bytes]]) -> Iterator[None]:
    try:
        yield
    finally:
        for p in procs:
            if p.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=10)


def run(way: str, workdir: Path, *, cut_s: float = 5.0, flaps: int = 10, down_s: float = 1.0,
        up_s: float = 2.0, ahead_m: float = 1.5, timeout_s: float = 240.0,
        code: Path = ROOT, lease_s: float | None = LEASE_S) -> Report:
    """One run: start both halves, cut once, flap, let the mission finish; measure.
    ``code``: the Shepherd checkout whose services and deployment files run (another one to
    measure it before a change: ``lease_s=None`` when its router has no ``--lease``)."""
    if way not in WAYS:
        raise ValueError(f"unknown way {way!r}; expected one of {', '.join(WAYS)}")
    workdir.mkdir(parents=True, exist_ok=True)
    report = Report(way)
    laptop_toml = workdir / "laptop.toml"
    start_x = 0.29  # deploy/sim-robot.toml leaves the simulator's default start
    text = re.sub(r"waypoints = \[\[.*?\]\]", f"waypoints = [[{start_x + ahead_m:.2f}, 0.0]]",
                  (code / "deploy/sim-laptop.toml").read_text(), count=1)
    laptop_toml.write_text(text)
    with Link() as link:
        ep = f"tcp/{link.robot_ip}:{PORT}"
        cli = ["-m", "services.tools.cli", "--log-level", "WARNING"]
        me = ["-m", "services.tools.partition", "probe", ep]
        lease = [] if lease_s is None else ["--lease", str(lease_s)]
        procs = [link.spawn(link.robot, [*cli, "router", "--listen", ep, *lease],
                            workdir / "router.log", workdir, code)]
        with _stopping(procs):
            _wait_for(lambda: "listening" in (workdir / "router.log").read_text(), 30,
                      "the router")
            procs.append(link.spawn(link.robot, [*cli, "run", str(code / "deploy/sim-robot.toml"),
                                                 "--connect", ep], workdir / "robot.log", workdir,
                                    code))
            procs.append(link.spawn(link.robot, [*me, str(workdir / "robot.jsonl")],
                                    workdir / "probe-robot.log", workdir))
            procs.append(link.spawn(link.laptop, [*me, str(workdir / "laptop.jsonl")],
                                    workdir / "probe-laptop.log", workdir))
            laptop_proc = link.spawn(link.laptop, [*cli, "run", str(laptop_toml), "--connect", ep,
                                                   "--duration", str(timeout_s)],
                                     workdir / "laptop.log", workdir, code)
            procs.append(laptop_proc)
            robot_jsonl = workdir / "robot.jsonl"

            def walking() -> bool:
                return any(r.get("k") == "ir" and r.get("cmd") == "walk_forward"
                           for r in _records(robot_jsonl))
            _wait_for(walking, 90, "the humanoid walking")
            time.sleep(1.0)
            rss0 = {"robot": _tree_rss_kb(procs[1].pid), "laptop": _tree_rss_kb(laptop_proc.pid)}
            plan = [cut_s] + [down_s] * flaps
            for i, down in enumerate(plan):
                t_cut = time.monotonic()
                link.cut(way)
                time.sleep(down)
                link.heal(way)
                report.cuts.append((t_cut, time.monotonic()))
                time.sleep(up_s if i < len(plan) - 1 else 0.0)
            laptop_rss = _tree_rss_kb(laptop_proc.pid)  # it exits when the mission is done
            try:
                laptop_proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                report.notes.append(f"the laptop did not finish within {timeout_s:.0f} s")
            done_t = time.monotonic()
            rss1 = {"robot": _tree_rss_kb(procs[1].pid), "laptop": laptop_rss}
            report.memory_growth = {k: (rss1[k] - rss0[k]) / rss0[k] for k in rss0 if rss0[k]}
    laptop_log = (workdir / "laptop.log").read_text(errors="replace")
    report.completed = "Mission summary" in laptop_log  # printed once the goal is reached
    if report.completed:
        report.done_after_last_heal_s = done_t - report.cuts[-1][1]
    if found := re.search(r"final error\s+([\d.]+) cm \(truth\)", laptop_log):
        report.final_error_cm = float(found.group(1))
    logs = "".join(p.read_text(errors="replace") for p in workdir.glob("*.log"))
    report.restarts = len(re.findall(r"restarting in", logs))
    from services.runtime.config import load_deployment
    sim: Any = load_deployment(code / "deploy/sim-robot.toml").settings_for("sim")
    fps = float(sim.fps)
    _measure(report, _records(workdir / "robot.jsonl"), _records(workdir / "laptop.jsonl"), fps)
    (workdir / "report.json").write_text(json.dumps(dataclasses.asdict(report), indent=1))
    return report


def _measure(report: Report, robot: list[dict[str, object]], laptop: list[dict[str, object]],
             fps: float) -> None:
    ir = [(float(r["t"]), str(r["cmd"]), r.get("sent")) for r in robot  # type: ignore[arg-type]
          if r.get("k") == "ir"]
    truth = [(float(r["t"]), float(r["x"]), float(r["y"])) for r in robot  # type: ignore[arg-type]
             if r.get("k") == "truth"]
    seqs = [(float(r["t"]), int(str(r["seq"]))) for r in robot  # type: ignore[arg-type]
            if r.get("k") == "truth" and "seq" in r]
    if len(seqs) > 1 and seqs[-1][0] > seqs[0][0]:
        report.sim_speed = round((seqs[-1][1] - seqs[0][1]) / fps / (seqs[-1][0] - seqs[0][0]), 2)
    # the humanoid's gait runs on the simulator's clock: 1.5 s of it
    late_s = 1.5 / min(1.0, max(report.sim_speed, 0.1))
    for t, cmd, sent in ir:
        if cmd == "stop" or sent is None:
            continue
        report.motion_sent += 1
        age = t - float(sent)  # type: ignore[arg-type]
        report.oldest_motion_s = max(report.oldest_motion_s, age)
        if age > STALE_S:
            report.stale_motion.append(round(age, 3))
    decided = [(float(r["sent"]), str(r["cmd"])) for r in laptop  # type: ignore[arg-type]
               if r.get("k") == "cmd"]
    arrived = [float(r["t"]) for r in robot if r.get("k") == "cmd"]  # type: ignore[arg-type]
    for t_cmd, t_heal in report.cuts:
        # the cut is in effect from the later of its command's start and the last controller
        # command that still came through (`ip netns exec iptables` can take 0.4 s on a
        # loaded machine: the humanoid cannot be asked to stop for a cut not yet made)
        first_stop = min((t for t, c, _ in ir if t > t_cmd and c == "stop"), default=t_heal)
        t_cut = max([t_cmd, *(t for t in arrived if t_cmd < t < min(first_stop, t_heal))])
        report.cut_late_s.append(round(t_cut - t_cmd, 3))
        before = [c for t, c, _ in ir if t <= t_cut]
        # the controller's last motion command before the cut (on its own host)
        last_motion = max((t for t, c in decided if t <= t_cut and c != "stop"), default=None)
        if before and before[-1] != "stop":
            stops = [t for t, c, _ in ir if t > t_cut and c == "stop"]
            if stops:
                report.stop_after_cut_s.append(round(stops[0] - t_cut, 3))
            else:
                report.stop_after_cut_s.append(float("inf"))
        if last_motion is not None:
            quiet = [(x, y) for t, x, y in truth if last_motion + late_s <= t <= t_heal]
            if len(quiet) >= 2:
                moved = max(abs(x - quiet[0][0]) + abs(y - quiet[0][1]) for x, y in quiet)
                if moved > 0.002:
                    report.moved_late_m.append(round(moved, 3))
            during = [(t, x, y) for t, x, y in truth if last_motion <= t <= t_heal]
            if during:
                _, xe, ye = during[-1]
                moving = [t for t, x, y in during if abs(x - xe) + abs(y - ye) > 0.001]
                report.still_after_last_motion_s.append(
                    round((max(moving) if moving else last_motion) - last_motion, 2))
            at_cut = [(x, y) for t, x, y in truth if t <= t_cut]
            in_cut = [(x, y) for t, x, y in truth if t_cut <= t <= t_heal]
            if at_cut and in_cut:
                report.coast_m.append(round(abs(in_cut[-1][0] - at_cut[-1][0])
                                            + abs(in_cut[-1][1] - at_cut[-1][1]), 3))
        fresh = [float(r["t"]) for r in laptop  # type: ignore[arg-type]
                 if r.get("k") == "pose" and float(r["t"]) > t_heal  # type: ignore[arg-type]
                 and float(r["lag"]) < STALE_S]  # type: ignore[arg-type]
        if fresh:
            report.fresh_pose_after_heal_s.append(round(fresh[0] - t_heal, 3))
        gone = [float(r["t"]) for r in robot  # type: ignore[arg-type]
                if r.get("k") == "alive" and not r["up"]
                and t_cut < float(r["t"]) < t_heal + 0.5]  # type: ignore[arg-type]
        if gone:
            report.token_gone_after_cut_s.append(round(gone[0] - t_cut, 3))


def summary(reports: list[Report]) -> str:
    """A markdown table of the runs."""
    def span(v: list[float]) -> str:
        return f"{min(v):.2f}-{max(v):.2f}" if v else "-"
    lines = ["| way | cuts | cut in effect after (s) | stop after cut (s) | "
             "token gone after cut (s) | motion cmds (> 0.5 s old) | oldest motion (s) | "
             "coast (cm) | moving after the last motion command (s) | "
             "fresh pose after heal (s) | done after last heal (s) | "
             "final error (cm) | restarts | memory | sim speed | holds |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in reports:
        mem = ", ".join(f"{k} {100 * g:+.0f}%" for k, g in r.memory_growth.items())
        done = f"{r.done_after_last_heal_s:.0f}" if r.done_after_last_heal_s else "not done"
        lines.append(
            f"| {r.way} | {len(r.cuts)} | {span(r.cut_late_s)} | {span(r.stop_after_cut_s)} | "
            f"{span(r.token_gone_after_cut_s)} | {r.motion_sent} ({len(r.stale_motion)}) | "
            f"{r.oldest_motion_s:.2f} | {span([100 * c for c in r.coast_m])} | "
            f"{span(r.still_after_last_motion_s)} | "
            f"{span(r.fresh_pose_after_heal_s)} | {done} | {r.final_error_cm} | {r.restarts} | "
            f"{mem} | {r.sim_speed:.2f} | "
            f"{'yes' if not r.failures() else '; '.join(r.failures())} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["probe"]:
        from services.runtime.session import zenoh_logging
        zenoh_logging()
        with contextlib.suppress(KeyboardInterrupt):
            asyncio.run(probe(args[1], Path(args[2])))
        return 0
    print("usage: python -m services.tools.partition probe ENDPOINT OUT.jsonl", file=sys.stderr)
    return 2


# -- what a short lease costs: stalls on the link ---------------------------------------------

_STALL_PEER = """
import sys, time
import zenoh
from services.runtime.session import ZenohSettings, zenoh_config
lease = None if sys.argv[3] == "none" else float(sys.argv[3])
s = zenoh.open(zenoh_config(ZenohSettings(mode="client", connect=[sys.argv[1]],
                                          multicast_scouting=False, lease_s=lease)))
if sys.argv[2] == "pub":
    while True:
        s.put("stall/t", repr(time.monotonic()))
        time.sleep(0.05)
else:
    s.declare_subscriber("stall/t", lambda m: print(time.monotonic(), m.payload.to_string(),
                                                    flush=True))
    time.sleep(3600)
"""


def stalls(lease_s: float | None, durations_s: list[float], workdir: Path) -> list[float]:
    """For each silent stall (both ways dropped) of the link: seconds from the heal to the
    first message *sent after it* arriving across (20 Hz publisher on the robot, subscriber on
    the laptop, both clients of the robot's router announcing ``lease_s``; None: Zenoh's)."""
    workdir.mkdir(parents=True, exist_ok=True)
    lease = "none" if lease_s is None else str(lease_s)
    with Link("s" + str(os.getpid())) as link:
        ep = f"tcp/{link.robot_ip}:{PORT}"
        router = ["-m", "services.tools.cli", "router", "--listen", ep]
        procs = [link.spawn(link.robot, router + ([] if lease_s is None else
                                                  ["--lease", lease]),
                            workdir / "router.log", workdir)]
        with _stopping(procs):
            _wait_for(lambda: "listening" in (workdir / "router.log").read_text(), 30,
                      "the router")
            procs.append(link.spawn(link.robot, ["-c", _STALL_PEER, ep, "pub", lease],
                                    workdir / "pub.log", workdir))
            procs.append(link.spawn(link.laptop, ["-c", _STALL_PEER, ep, "sub", lease],
                                    workdir / "sub.log", workdir))
            time.sleep(3.0)
            heals = []
            for d in durations_s:
                link.cut("drop")
                time.sleep(d)
                link.heal("drop")
                heals.append(time.monotonic())
                time.sleep(6.0)
    rows = []
    for line in (workdir / "sub.log").read_text().splitlines():
        with contextlib.suppress(ValueError):
            got, sent = (float(v) for v in line.split())
            rows.append((got, sent))
    out = []
    for heal in heals:
        after = [got for got, sent in rows if sent >= heal]
        out.append(round(min(after) - heal, 2) if after else float("inf"))
    return out


if __name__ == "__main__":
    raise SystemExit(main())
