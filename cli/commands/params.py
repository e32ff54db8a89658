"""uav-depth params default|check|table."""

from __future__ import annotations

import argparse


def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    sub.add_parser("default", help="print the built-in manual baseline as a parameter file")
    c = sub.add_parser("check", help="validate a parameter file; prints its hash")
    c.add_argument("file")
    sub.add_parser("table", help="print the markdown table of keys, bounds and the paper's symbols")


def run(args: argparse.Namespace) -> int:
    from uav_depth.core.params import DEFAULT_PARAMS, dump_params, load_params, params_table_markdown

    if args.action == "default":
        print(dump_params(DEFAULT_PARAMS), end="")
    elif args.action == "check":
        params = load_params(args.file)
        print(f"{args.file}: valid, hash {params.hash()}")
    else:
        print(params_table_markdown())
    return 0
