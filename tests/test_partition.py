"""Issue 20, through real networking: a short lease makes a partition drop the liveliness
token, and a real link between a simulated robot and laptop (two network namespaces and a veth
pair) cut while the humanoid walks never lets an old command move it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from services.runtime.session import ZenohSettings, zenoh_config
from services.tools import partition
from tests.conftest import ROOT, free_port

_TOKEN_HOLDER = """
import sys, time, zenoh
from services.runtime.session import ZenohSettings, zenoh_config
s = zenoh.open(zenoh_config(ZenohSettings(mode="client", connect=[sys.argv[1]],
                                          multicast_scouting=False, lease_s=1.5)))
token = s.liveliness().declare_token("shepherd/alive/holder")
print("up", flush=True)
time.sleep(60)
"""


@pytest.mark.slow
def test_a_silent_host_loses_its_liveliness_token_within_its_lease(router: str):
    """SIGSTOP: the process's connection stays open but nothing comes from it, as when the
    Wi-Fi drops. Zenoh's default lease (10 s) would keep the token that long."""
    holder = subprocess.Popen([sys.executable, "-c", _TOKEN_HOLDER, router],
                              stdout=subprocess.PIPE, text=True, cwd=ROOT,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
    events: list[tuple[float, bool]] = []
    s = zenoh.open(zenoh_config(ZenohSettings(mode="peer", connect=[router],
                                              multicast_scouting=False)))
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "up"
        sub = s.liveliness().declare_subscriber(
            "shepherd/alive/holder", lambda sample: events.append(
                (time.monotonic(), sample.kind == zenoh.SampleKind.PUT)), history=True)
        deadline = time.monotonic() + 5
        while not events and time.monotonic() < deadline:
            time.sleep(0.05)
        assert events and events[0][1], "the token never appeared"
        os.kill(holder.pid, signal.SIGSTOP)
        silent = time.monotonic()
        while len(events) < 2 and time.monotonic() - silent < 8:
            time.sleep(0.05)
        sub.undeclare()
    finally:
        s.close()
        holder.kill()
        holder.communicate(timeout=10)
    gone = [t - silent for t, up in events if not up]
    assert gone, "the token stayed"
    print(f"\nliveliness token gone {1000 * gone[0]:.0f} ms after the host went silent "
          "(lease 1.5 s)")
    assert gone[0] < 2.5


def test_the_zenoh_table_sets_the_lease_and_keep_alive():
    conf = zenoh_config(ZenohSettings(lease_s=1.5, keep_alive=4))
    assert conf.get_json("transport/link/tx/lease") == "1500"
    assert conf.get_json("transport/link/tx/keep_alive") == "4"
    # a silently dropped link is tried again every few seconds, not after TCP's backoff
    assert conf.get_json("transport/unicast/open_timeout") == "2000"
    assert json.loads(conf.get_json("connect/retry"))["period_max_ms"] <= 1000
    from services.runtime.config import load_deployment
    for name in ("sim-robot", "sim-laptop", "robot", "laptop"):
        dep = load_deployment(ROOT / "deploy" / f"{name}.toml")
        assert dep.zenoh.lease_s is not None and dep.zenoh.lease_s <= 2.0, name
        assert dep.zenoh.mode == "client", name  # through the router only (see departures)


_LOGGED_SESSION = """
import sys, zenoh
from services.runtime.session import ZenohSettings, open_session, zenoh_logging
zenoh_logging()
with open_session(ZenohSettings(mode="peer", listen=[sys.argv[1]], multicast_scouting=False)):
    pass
"""


@pytest.mark.parametrize("rust_log", ["zenoh::net::runtime::orchestrator=info", ""])
def test_rust_log_shows_zenohs_own_log(rust_log: str):
    """A user watching a reconnection sets RUST_LOG (docs/deployments/robot-laptop.md);
    without it Zenoh says nothing."""
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    env.update(PYTHONPATH=str(ROOT), **({"RUST_LOG": rust_log} if rust_log else {}))
    done = subprocess.run([sys.executable, "-c", _LOGGED_SESSION,
                           f"tcp/127.0.0.1:{free_port()}"], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=60)
    assert done.returncode == 0, done.stderr
    assert ("Zenoh can be reached at" in done.stdout) == bool(rust_log), done.stdout


WHY_NOT = partition.unavailable()


@pytest.mark.slow
@pytest.mark.skipif(bool(WHY_NOT), reason=f"no network namespaces here: {WHY_NOT}")
@pytest.mark.parametrize("way", partition.WAYS)
def test_a_real_link_cut_and_flapped_while_the_humanoid_walks(tmp_path: Path, way: str):
    """deploy/sim-robot.toml behind `shepherd router` in one namespace, deploy/sim-laptop.toml
    in another, the mission 1.5 m ahead; the link cut 5 s, then flapped twice (`shepherd
    partition` runs the issue's ten flaps)."""
    report = partition.run(way, tmp_path, cut_s=5.0, flaps=2, timeout_s=150)
    print("\n" + partition.summary([report]))
    assert report.motion_sent > 10  # the humanoid did walk, between the cuts too
    assert not report.stale_motion  # no motion command older than 0.5 s reached it
    assert len(report.stop_after_cut_s) >= 1 and max(report.stop_after_cut_s) < 1.0
    assert len(report.fresh_pose_after_heal_s) == len(report.cuts)
    # a reconnection attempt is given up after 2 s (open_timeout_s) and retried within 1 s:
    # poses are back about 1-2 s after a heal, unless the router's close of the dropped link
    # lingers (zenoh#1101: 7.3 s seen after a 5 s cut, 1 run in 20 under load here)
    assert max(report.fresh_pose_after_heal_s) < partition.FRESH_BOUND_S
    assert report.completed, (tmp_path / "laptop.log").read_text()[-3000:]
    assert report.restarts == 0
    assert not report.moved_late_m, report.moved_late_m


def test_a_stop_is_timed_from_when_the_cut_took_effect_not_from_its_command():
    """`iptables` in a namespace can take 0.4 s on a loaded machine: commands that still came
    through after the cut command started show the cut was not yet made; the stop is timed
    from the last of them (and never from before the command)."""
    robot: list[dict[str, object]] = [
        {"k": "ir", "t": 9.5, "cmd": "walk_forward", "sent": 9.49},
        {"k": "cmd", "t": 9.8, "cmd": "walk_forward", "sent": 9.8},
        {"k": "cmd", "t": 10.2, "cmd": "walk_forward", "sent": 10.2},   # came through
        {"k": "cmd", "t": 10.4, "cmd": "walk_forward", "sent": 10.4},   # came through
        {"k": "ir", "t": 10.92, "cmd": "stop", "sent": None},            # the dead-man
    ]
    laptop = [{"k": "cmd", "t": t, "cmd": "walk_forward", "sent": t} for t in (9.8, 10.2, 10.4)]
    late = partition.Report("drop", cuts=[(10.0, 11.0)])
    partition._measure(late, robot, laptop, fps=30.0)
    assert late.cut_late_s == [0.4] and late.stop_after_cut_s == [0.52]
    prompt = partition.Report("drop", cuts=[(10.3, 11.0)])
    partition._measure(prompt, robot[:3] + robot[4:], laptop, fps=30.0)
    assert prompt.cut_late_s == [0.0] and prompt.stop_after_cut_s == [0.62]
