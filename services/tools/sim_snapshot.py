"""``shepherd sim snapshot``: what the camera sees, from a running system or a fresh scene."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

import cv2


def add_sim_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("sim", help="simulator tools")
    ssub = p.add_subparsers(dest="sim_cmd", required=True)
    s = ssub.add_parser("snapshot", help="write what the camera sees now to a PNG")
    s.add_argument("--out", default="frame.png", help="the PNG to write")
    s.add_argument("--file", help="deployment file for a fresh scene (default deploy/sim.toml)")
    s.add_argument("--fresh", action="store_true", help="do not look for a running system")
    s.add_argument("--timeout", type=float, default=1.5, help="seconds to wait for a frame")
    s.add_argument("--connect", "-e", action="append", default=[], metavar="EP",
                   help="Zenoh endpoint of the running system (repeatable)")
    s.add_argument("--namespace", default="shepherd", help="key prefix (default: shepherd)")
    s.set_defaults(func=cmd_snapshot)


async def _grab(args: argparse.Namespace):
    from schemas import Keys
    from services.runtime.bus import Bus
    from services.runtime.session import LOCAL_ENDPOINT, ZenohSettings, open_session
    settings = ZenohSettings(connect=args.connect or [LOCAL_ENDPOINT],
                             multicast_scouting=not args.connect)
    with open_session(settings) as session:
        bus = Bus(session, Keys(args.namespace), "snapshot")
        try:
            frames = bus.subscribe_frames()
            try:
                return await frames.recv(args.timeout)
            except TimeoutError:
                return None
        finally:
            bus.close()


def cmd_snapshot(args: argparse.Namespace) -> int:
    from services.data import DEFAULT_DEPLOYMENT
    from services.runtime.config import ConfigError, load_deployment
    frame = None if args.fresh else asyncio.run(_grab(args))
    if frame is not None:
        image, source = frame.image, f"live frame seq={frame.header.seq}"
    else:
        from services.sim.service import Settings, build_world
        try:
            dep = load_deployment(args.file or DEFAULT_DEPLOYMENT)
        except ConfigError as err:
            print(f"shepherd: {err}", file=sys.stderr)
            return 2
        config = dep.settings.get("sim") or Settings()
        sim = build_world(config, dep.geometry, dep.world)
        image, source = sim.render().image, "fresh simulated scene"
    out = Path(args.out)
    if not cv2.imwrite(str(out), image):
        print(f"shepherd: cannot write {out}", file=sys.stderr)
        return 2
    print(f"wrote {out} ({image.shape[1]}x{image.shape[0]}, {source})")
    return 0
