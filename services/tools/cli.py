"""The ``shepherd`` command. Argument parsing lives here and nowhere else."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
import time
from importlib import metadata
from pathlib import Path

from schemas import Command, Message
from services.data import DEFAULT_DEPLOYMENT
from services.runtime.session import LOCAL_ENDPOINT, ZenohSettings, zenoh_logging


def _version() -> str:
    try:
        return metadata.version("shepherd")
    except metadata.PackageNotFoundError:
        return "0+unknown"


def _zenoh_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--connect", "-e", action="append", default=[], metavar="EP",
                   help="Zenoh endpoint to connect to, e.g. tcp/192.168.1.10:7447 (repeatable)")
    p.add_argument("--listen", "-l", action="append", default=[], metavar="EP",
                   help="Zenoh endpoint to listen on (repeatable)")
    p.add_argument("--mode", choices=["peer", "client"], default="peer",
                   help="the Zenoh session's role")
    p.add_argument("--namespace", default="shepherd", help="key prefix (default: shepherd)")


def _session_settings(args: argparse.Namespace) -> ZenohSettings:
    # Explicit endpoints mean the user knows where to go: no multicast scouting then.
    # Without any, look for the local default deployment (deploy/sim.toml listens there).
    explicit = bool(args.connect or args.listen)
    return ZenohSettings(mode=args.mode, connect=args.connect or [LOCAL_ENDPOINT],
                         listen=args.listen, multicast_scouting=not explicit)


def cmd_run(args: argparse.Namespace) -> int:
    from services.runtime.config import ConfigError, load_deployment
    from services.runtime.launcher import run_deployment
    path = Path(args.file) if args.file else DEFAULT_DEPLOYMENT
    try:
        dep = load_deployment(path)
    except ConfigError as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2
    if args.connect:
        dep.zenoh.connect = args.connect
        dep.zenoh.multicast_scouting = False
    if args.listen:
        dep.zenoh.listen = args.listen
    import zenoh
    try:
        return asyncio.run(run_deployment(dep, only=args.only or None, duration=args.duration,
                                          processes=args.processes, child=args.child))
    except KeyError as err:
        print(f"shepherd: {err.args[0]}", file=sys.stderr)
        return 2
    except zenoh.ZError as err:
        eps = ", ".join(dep.zenoh.listen + dep.zenoh.connect) or "the default endpoints"
        print(f"shepherd: cannot open the Zenoh session ({eps}): {str(err).split(' at ')[0]}"
              " - is another shepherd run using it? Pick others with --listen/--connect.",
              file=sys.stderr)
        return 2


def cmd_echo(args: argparse.Namespace) -> int:
    from services.tools.echo import echo
    try:
        return asyncio.run(echo(_session_settings(args), args.namespace, args.key_expr,
                                count=args.count, duration=args.duration, raw=args.json))
    except KeyboardInterrupt:
        return 0


def cmd_router(args: argparse.Namespace) -> int:
    import zenoh

    from services.runtime.session import zenoh_config
    # a native config's own listen endpoints (e.g. TLS) hold unless --listen replaces them
    listen = args.listen or ([] if args.config else ["tcp/0.0.0.0:7447"])
    settings = ZenohSettings(mode="router", listen=listen, multicast_scouting=False,
                             config_file=Path(args.config) if args.config else None,
                             lease_s=args.lease)
    try:
        session = zenoh.open(zenoh_config(settings))
    except (zenoh.ZError, FileNotFoundError) as err:
        print(f"shepherd: cannot start the router: {err}", file=sys.stderr)
        return 2
    try:
        shown = listen or _config_endpoints(Path(args.config))
        print(f"shepherd router listening on {', '.join(shown)}", flush=True)
        try:
            if args.duration:
                time.sleep(args.duration)
            else:
                while True:
                    time.sleep(3600)
        except KeyboardInterrupt:
            pass
    finally:
        session.close()
    return 0


def _config_endpoints(path: Path) -> list[str]:
    """The listen endpoints a native Zenoh config names (for the start-up line)."""
    import zenoh
    try:
        text = zenoh.Config.from_file(str(path)).get_json("listen/endpoints")
    except Exception:
        return [f"the endpoints of {path}"]
    return list(json.loads(text)) if text and text != "null" else [f"Zenoh's default ({path})"]


def cmd_schemas(args: argparse.Namespace) -> int:
    from schemas import ALL_MODELS
    out = {m.__name__: {"encoding": m.zenoh_encoding(), "schema": m.model_json_schema()}
           for m in ALL_MODELS}
    from schemas.keys import TOPICS
    out["_keys"] = {k: (v.__name__ if v else "raw frame, FrameHeader attachment")
                    for k, v in TOPICS.items()}
    print(json.dumps(out, indent=2))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from services.tools.bench import run_bench
    return run_bench(args.only, quick=args.quick)


def cmd_publish(args: argparse.Namespace, suffix: str, message: Message) -> int:
    from services.tools.echo import publish_once
    return asyncio.run(publish_once(_session_settings(args), args.namespace, suffix, message))


def cmd_mission(args: argparse.Namespace) -> int:
    from schemas import IrCommand, MissionGoal
    from schemas.keys import IR_COMMAND, MISSION_GOAL
    if args.mission_cmd == "goto":
        if len(args.coords) % 2:
            print("shepherd: mission goto needs X Y pairs (metres)", file=sys.stderr)
            return 2
        pts = [(args.coords[i], args.coords[i + 1]) for i in range(0, len(args.coords), 2)]
        return cmd_publish(args, MISSION_GOAL, MissionGoal(waypoints=pts,
                                                           tolerance_m=args.tolerance))
    rc = cmd_publish(args, MISSION_GOAL, MissionGoal(waypoints=[]))
    return rc or cmd_publish(args, IR_COMMAND, IrCommand(command=Command.STOP))


def cmd_ir(args: argparse.Namespace) -> int:
    from schemas import IrBackendRequest, IrCommand
    from schemas.keys import IR_BACKEND, IR_COMMAND
    if args.ir_cmd == "send":
        return cmd_publish(args, IR_COMMAND, IrCommand(command=args.command))
    options = dict(o.split("=", 1) for o in args.option)
    if args.port:
        options["port"] = args.port
    if args.baud:
        options["baud"] = args.baud
    if args.socket:
        options["socket"] = args.socket
    return cmd_publish(args, IR_BACKEND, IrBackendRequest(backend=args.backend, options=options))


def cmd_record(args: argparse.Namespace) -> int:
    from services.tools.recorder import record
    try:
        return asyncio.run(record(_session_settings(args), args.namespace, Path(args.out),
                                  args.key_exprs, args.duration, args.jpeg))
    except KeyboardInterrupt:
        return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from services.tools.recorder import replay
    if not Path(args.inp).is_file():
        print(f"shepherd: no such recording: {args.inp}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(replay(_session_settings(args), Path(args.inp), args.speed,
                                  args.only or None, namespace=args.namespace,
                                  to_namespace=args.to_namespace, actuate=args.actuate))
    except ValueError as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2


def cmd_soak(args: argparse.Namespace) -> int:
    from services.runtime.config import ConfigError, load_deployment
    from services.tools.soak import soak
    try:
        dep = load_deployment(Path(args.file) if args.file else DEFAULT_DEPLOYMENT)
    except ConfigError as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2
    if args.listen:
        dep.zenoh.listen = args.listen
    return asyncio.run(soak(dep, args.minutes, args.sample_s))


def cmd_partition(args: argparse.Namespace) -> int:
    from services.tools import partition
    why = partition.unavailable()
    if why:
        print(f"shepherd: cannot cut a link here: {why}", file=sys.stderr)
        return 2
    out = Path(args.out)
    if args.stalls:
        durations = [0.5, 1.0, 1.3, 1.7, 2.5]
        print("| stall (s) | " + " | ".join(f"{d:.1f}" for d in durations) + " |")
        print("|---|" + "---|" * len(durations))
        for lease in (partition.LEASE_S, None):
            got = partition.stalls(lease, durations, out / f"stalls-{lease or 'default'}")
            name = f"lease {lease} s" if lease else "Zenoh's default lease"
            print(f"| {name} | " + " | ".join(f"{g:.2f}" for g in got) + " |", flush=True)
        return 0
    reports = []
    for way in args.ways.split(","):
        r = partition.run(way, out / way, cut_s=args.cut, flaps=args.flaps)
        reports.append(r)
        print(partition.summary([r]).splitlines()[-1], flush=True)
    table = partition.summary(reports)
    (out / "report.md").write_text(table + "\n")
    print(table)
    return 0 if all(not r.failures() for r in reports) else 1


def cmd_experiments(args: argparse.Namespace) -> int:
    from services.tools.experiments import run
    return run(Path(args.out), quick=args.quick)


def cmd_compile(args: argparse.Namespace) -> int:
    from services.tools.kernels import compile_kernels
    compile_kernels()
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="shepherd", description=__doc__)
    parser.add_argument("--version", action="version", version=f"shepherd {_version()}")
    parser.add_argument("--log-level", default="INFO",
                        help="DEBUG, INFO, WARNING or ERROR")
    sub = parser.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("run", help="run the services a deployment file names", description=(
        "Each service an asyncio task in one process, or each its own process with "
        "--processes (or process = true in its table); crashed services restart with "
        "backoff; SIGINT/SIGTERM stop all within 2 s, each sending stop to the humanoid."))
    p.add_argument("file", nargs="?",
                   help="deployment file (default: deploy/sim.toml, shipped in the package)")
    p.add_argument("--connect", "-e", action="append", default=[], metavar="EP",
                   help="Zenoh endpoint to connect to, instead of the file's (repeatable)")
    p.add_argument("--listen", "-l", action="append", default=[], metavar="EP",
                   help="Zenoh endpoint to listen on, instead of the file's (repeatable)")
    p.add_argument("--duration", type=float, help="stop after S seconds")
    p.add_argument("--only", action="append", default=[], metavar="NAME",
                   help="run only this service (repeatable)")
    p.add_argument("--processes", action="store_true", help="one OS process per service")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("echo", help="print decoded messages on a key expression", description=(
        "One readable line per message (frames: seq, size, rate; checked, never decoded); "
        "control characters from the wire are escaped; --json prints the payloads."))
    p.add_argument("key_expr", nargs="?", default="shepherd/**",
                   help="Zenoh key expression, e.g. 'shepherd/humanoid/*'")
    _zenoh_args(p)
    p.add_argument("--count", type=int, help="exit after N messages")
    p.add_argument("--duration", type=float, help="exit after S seconds")
    p.add_argument("--json", action="store_true", help="print the raw JSON")
    p.set_defaults(func=cmd_echo)

    p = sub.add_parser("router", help="run a Zenoh router (no zenohd needed)", description=(
        "A Zenoh router in Python, so hosts can meet without zenohd; with --config it "
        "listens where the native config says (e.g. TLS) unless --listen is given."))
    p.add_argument("--listen", "-l", action="append", default=[], metavar="EP",
                   help="endpoint to listen on (default tcp/0.0.0.0:7447; repeatable)")
    p.add_argument("--config", help="native Zenoh config file (TLS, auth, ACL)")
    p.add_argument("--lease", type=float, metavar="S", help=(
        "the lease (s) announced to the robot's and laptop's sessions: a partitioned link "
        "closes after this long (Zenoh's default 10 s; the split deployments use 1.5 s)"))
    p.add_argument("--duration", type=float, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_router)

    p = sub.add_parser("schemas", help="print the JSON Schema of every message",
                       description="JSON Schemas of all messages and the key table.")
    p.set_defaults(func=cmd_schemas)

    p = sub.add_parser("compile", help="compile the hot-path kernels now (first run: ~40 s)",
                       description="Into their on-disk cache; make runs it at install, and "
                       "services do it on start when needed.")
    p.set_defaults(func=cmd_compile)

    p = sub.add_parser("bench", help="benchmarks beside their references")
    p.add_argument("--only", action="append", default=[],
                   help="bus, vertices, pose, calibration, e2e (repeatable)")
    p.add_argument("--quick", action="store_true", help="fewer repetitions")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("mission", help="send the humanoid somewhere, or stop it")
    msub = p.add_subparsers(dest="mission_cmd", required=True)
    g = msub.add_parser("goto", help="waypoints X Y [X Y ...] in metres, world frame")
    g.add_argument("coords", nargs="+", type=float, metavar="X Y",
                   help="waypoints, world metres")
    g.add_argument("--tolerance", type=float, default=None,
                   help="goal tolerance l, metres (default: the controller's)")
    _zenoh_args(g)
    s = msub.add_parser("stop", help="clear the mission and send stop")
    _zenoh_args(s)
    p.set_defaults(func=cmd_mission)

    p = sub.add_parser("ir", help="send an IR command or switch the IR backend")
    isub = p.add_subparsers(dest="ir_cmd", required=True)
    s = isub.add_parser("send", help="send one command to the humanoid (ir/command)")
    s.add_argument("command", choices=["walk_forward", "walk_backward", "turn_left",
                                       "turn_right", "stop"], help="the command")
    _zenoh_args(s)
    b = isub.add_parser("backend", help="switch the IR transmitter's backend (ir/backend)")
    b.add_argument("backend", choices=["serial", "lirc", "sim", "log"], help="the backend")
    b.add_argument("--port", help="serial: the device, e.g. /dev/ttyACM0")
    b.add_argument("--baud", type=int, help="serial: the baud rate (the firmware's: 115200)")
    b.add_argument("--socket", help="lirc: lircd's socket")
    b.add_argument("--option", "-o", action="append", default=[], metavar="KEY=VALUE",
                   help="any other backend option (repeatable)")
    _zenoh_args(b)
    p.set_defaults(func=cmd_ir)

    p = sub.add_parser("record", help="record bus traffic to an MCAP file", description=(
        "A JSON Schema per channel; frames lossless, or JPEG with --jpeg."))
    p.add_argument("out", help="OUT.mcap")
    p.add_argument("key_exprs", nargs="*", help="default: <namespace>/**")
    _zenoh_args(p)
    p.add_argument("--duration", type=float, help="stop after S seconds (default: Ctrl-C)")
    p.add_argument("--jpeg", type=int, metavar="Q", help="store frames as JPEG of quality Q")
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("replay", help="publish an MCAP recording back at its recorded pace",
                       description="The keys that move a robot (ir/**, mission/**, "
                       "camera/goal) are left out unless --actuate.")
    p.add_argument("inp", metavar="IN.mcap", help="a recording made by shepherd record")
    _zenoh_args(p)
    p.add_argument("--speed", type=float, default=1.0, help="pace: 2 is twice as fast")
    p.add_argument("--only", action="append", default=[], metavar="KEY_EXPR",
                   help="replay only matching keys (repeatable)")
    p.add_argument("--actuate", action="store_true",
                   help="also replay the keys that move a robot (ir/**, mission/**, camera/goal)")
    p.add_argument("--to-namespace", metavar="NS",
                   help="republish <namespace>/... under NS/... (e.g. to watch a run offline)")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("soak", help="run the simulated mission back and forth; watch memory",
                       description="For a long time; the memory growth is reported.")
    p.add_argument("file", nargs="?",
                   help="deployment file (default: deploy/sim.toml, shipped in the package)")
    p.add_argument("--minutes", type=float, default=30.0, help="how long")
    p.add_argument("--sample-s", type=float, default=60.0, help="memory sampling period")
    p.add_argument("--listen", "-l", action="append", default=[], metavar="EP",
                   help="Zenoh endpoint to listen on, instead of the file's (repeatable)")
    p.set_defaults(func=cmd_soak)

    p = sub.add_parser("partition", help=(
        "cut a real link between a simulated robot and laptop (root: network namespaces)"))
    p.add_argument("--ways", default="down,drop,laptop",
                   help="how to cut, comma-separated: down, drop, laptop")
    p.add_argument("--cut", type=float, default=5.0, help="the first cut (s)")
    p.add_argument("--flaps", type=int, default=10, help="then this many 1 s down / 2 s up")
    p.add_argument("--out", default="partition", help="folder for logs and report.md")
    p.add_argument("--stalls", action="store_true", help=(
        "instead: what a short lease costs, as the time from the end of silent stalls of "
        "0.5-2.5 s to the first fresh message, with the split deployments' lease and Zenoh's"))
    p.set_defaults(func=cmd_partition)

    p = sub.add_parser("experiments", help="the paper's experiments in simulation: report",
                       description="The paper's Table 3, Fig. 9, Fig. 10 and critical-angle "
                       "study, each also with our calibration of the camera beside its truth, "
                       "and the control experiment over 20 seeds on the stepping humanoid: "
                       "report.md and PNGs (matplotlib with the plot extra).")
    p.add_argument("--out", default="experiments", help="folder for report.md and plots")
    p.add_argument("--quick", action="store_true", help="fewer trials")
    p.set_defaults(func=cmd_experiments)

    from services.tools.sim_snapshot import add_sim_parser
    add_sim_parser(sub)
    from services.tools.calibrate import add_calibrate_parser
    add_calibrate_parser(sub)
    from services.tools.marker import add_marker_parser
    add_marker_parser(sub)
    from services.tools.docs import add_docs_parser
    add_docs_parser(sub)
    return parser


def use_fast_event_loop() -> None:
    """uvloop's event loop where it is installed (a dependency except on Windows): about
    0.1 ms less from frame to pose at 30 fps here than asyncio's own loop."""
    try:
        import uvloop
    except ImportError:
        return
    asyncio.set_event_loop_policy(uvloop.EventLoopPolicy())


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    use_fast_event_loop()
    zenoh_logging()
    logging.basicConfig(level=getattr(logging, str(args.log_level).upper(), logging.INFO),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s",
                        datefmt="%H:%M:%S")
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
