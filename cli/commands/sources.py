"""uav-depth sources: list the frame sources (the names ``source.kind`` accepts) and their keys."""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--keys", action="store_true", help="also list every source's config keys")
    p.add_argument("--probe", action="store_true",
                   help="also look for hardware: V4L2 devices and OAK devices (takes about a second)")


def run(args: argparse.Namespace) -> int:
    import glob

    from uav_depth.cli.sources import SOURCES
    from uav_depth.daemon.sources import source_keys

    width = max(map(len, SOURCES))
    for kind, (_, _, help_text) in SOURCES.items():
        print(f"{kind:<{width}}  {help_text}")
        if args.keys:
            for k in source_keys(kind, SOURCES):
                default = "null" if k.default is None else k.default
                print(f"{'':<{width}}    {k.name} (default {default}): {k.doc}")
    if args.probe:
        videos = sorted(glob.glob("/dev/video*"))
        print(f"\nV4L2 devices: {', '.join(videos) if videos else 'none'}")
        try:
            import depthai as dai

            found = [d.getDeviceId() for d in dai.Device.getAllAvailableDevices()]
            print(f"OAK devices: {', '.join(found) if found else 'none'}")
        except ImportError:
            print("OAK devices: depthai not installed (pip install 'uav-depth[oak]')")
    return 0
