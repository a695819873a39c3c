"""`uwsimnet deploy`: an inventory to per-machine router and client configurations (deploy/render.py)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from ..deploy import render


def add_commands(top: argparse._SubParsersAction) -> None:
    """`uwsimnet deploy render|certs|check`."""
    ap = top.add_parser("deploy", help="lab deployment: router/client configs, TLS, access control",
                        description=render.__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="deploy_cmd", required=True)
    r = sub.add_parser("render", help="write the router and client configurations of an inventory")
    r.add_argument("inventory")
    r.add_argument("-o", "--out", required=True, help="output directory (one sub-directory per host)")
    c = sub.add_parser("certs", help="print the make-certs.sh command for an inventory")
    c.add_argument("inventory")
    c.add_argument("tlsdir", help="where make-certs.sh writes the CA and certificates")
    k = sub.add_parser("check", help="load every generated configuration in zenoh")
    k.add_argument("outdir")
    ap.set_defaults(fn=run)


def run(args: argparse.Namespace) -> int:
    try:
        if args.deploy_cmd == "check":
            problems = render.check(args.outdir)
            for p in problems:
                print(p, file=sys.stderr)
            print(f"{args.outdir}: {'ok' if not problems else f'{len(problems)} problem(s)'}")
            return 2 if problems else 0
        inv = render.load_inventory(args.inventory)
        if args.deploy_cmd == "certs":
            print(shlex.join([render.make_certs_script(), args.tlsdir, *render.cert_specs(inv)]))
            return 0
        known_file = Path(args.out) / "passwords.txt"
        known = render.parse_passwords(known_file.read_text(encoding="utf-8")) if known_file.is_file() else None
        paths = render.write(render.render(inv, known), args.out)
        for p in paths:
            print(p)
        return 0
    except render.InventoryError as e:
        print(e, file=sys.stderr)
        return 2

