"""``sparsebtf view``: the real-time WebGL2 viewer of a coded BTF (paper Eq. 5/6 per fragment).

    sparsebtf view stone.coded.h5                  # serve on 127.0.0.1 (a free port), open it
    sparsebtf view stone.coded.h5 --no-browser     # only print the URL; Ctrl-C stops
    sparsebtf view stone.coded.h5 --export site/   # a static page + data, for any HTTP server

The page needs WebGL2 with 32-bit float and integer textures (every desktop browser since
2021, and headless Chromium on SwiftShader). Files coded with one patch size and with adaptive
patch sizes (``encode --adaptive-patches``) are both shown.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from ._args import check_output_dir, check_tau, integer

__all__ = ["register"]


def cmd_view(args: argparse.Namespace) -> int:
    from ..patch_tree import AdaptiveCodedBTF
    from ..rendering.viewer import build_bundle, export, serve
    from ..runtime import AdaptiveRuntimeBTF, RuntimeBTF
    from ..storage import load_coded_with_model

    tau = check_tau(args.tau)
    check_output_dir(args.export, "--export")
    coded = load_coded_with_model(args.coded, args.model, adaptive=True)
    # adaptive patch sizes: the nodes of the tree are the points (a fraction --tau applies to
    # each size's coded tau, an integer one caps every node)
    rt = (AdaptiveRuntimeBTF(coded, tau) if isinstance(coded, AdaptiveCodedBTF)
          else RuntimeBTF(coded, tau))  # fmt: skip
    bundle = build_bundle(rt, neighbours=not args.no_neighbours)
    mib = bundle.manifest["bytes"] / 2**20
    if args.export:
        out = export(bundle, args.export)
        print(
            f"wrote {out}/ (index.html, viewer.js, shaders, manifest.json, data.bin: {mib:.1f} "
            f"MiB of textures); serve it over HTTP, e.g. `python -m http.server -d {out}` "
            "(browsers refuse to fetch data from file://)"
        )
        return 0
    if not _is_loopback(args.host):
        print(
            f"sparsebtf: warning: serving on {args.host!r}, not the loopback address: any "
            "machine that can reach this one can open the viewer and download the coded "
            "material; use --host 127.0.0.1 to keep it local",
            file=sys.stderr,
        )
    server = serve(bundle, args.host, args.port)
    print(f"SparseBTF viewer of {args.coded} ({mib:.1f} MiB of textures) at {server.url}")
    print("press Ctrl-C to stop")
    if not args.no_browser:
        import webbrowser

        if not webbrowser.open(server.url):
            print("(no browser could be started: open the URL yourself)")
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        print("stopped")
    finally:
        server.close()
    return 0


def _is_loopback(host: str) -> bool:
    """Whether ``host`` is this machine only (127.0.0.0/8, ::1, or a name resolving there)."""
    import ipaddress
    import socket

    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False
    return bool(infos) and all(ipaddress.ip_address(i[4][0]).is_loopback for i in infos)


def register(sub: Any) -> None:
    """Add the ``view`` subcommand to the main parser's subparsers."""
    s = sub.add_parser("view", help="real-time WebGL2 viewer of a coded BTF (browser)")
    s.add_argument("coded", help="coded BTF file (.h5 from 'sparsebtf encode')")
    s.add_argument("-m", "--model", help="model file or bundled model name (default: the one "
                   "the coded file names)")
    s.add_argument(
        "--tau",
        help="load-time level of detail: 'Y,U,V', one integer, or a fraction such as 0.5 "
        "(default: every stored coefficient; the page's slider lowers it further)",
    )
    s.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    s.add_argument("--port", type=int, default=0, help="port (default: a free one)")
    s.add_argument("--no-browser", action="store_true", help="only print the URL")
    s.add_argument("--export", metavar="DIR", help="write a static page with its data into DIR")
    s.add_argument(
        "--no-neighbours",
        action="store_true",
        help="scan every direction per fragment instead of the 8-candidate tables",
    )
    s.set_defaults(func=cmd_view, checks={"port": integer(0, 65535, unit="(0: a free port)")})
