"""Real-time WebGL2 viewer of a coded BTF (issue 6): texture packing, static export, local server.

The page (``static/index.html`` + ``static/viewer.js``) evaluates the paper's Eq. 5 (one BTF
value from the sparse codes) and Eq. 6 (coefficient-space angular interpolation) per fragment
with ``shaders/sparsebtf_lookup.glsl``, the GLSL ES 3.00 twin of
:meth:`sparsebtf.runtime.RuntimeBTF.evaluate`. This module turns a
:class:`~sparsebtf.runtime.RuntimeBTF`, or an :class:`~sparsebtf.runtime.AdaptiveRuntimeBTF`
(a material coded with adaptive patch sizes: its tree's nodes are the points, found per texel
in a table, :mod:`.tree`), into what the page loads:

* ``manifest.json`` — sizes, uniforms, and for every texture its format, width, height and
  byte offset in the binary;
* ``data.bin`` — every texture's texels back to back (little endian, 16-byte aligned). Each 1D
  array of n entries lies in a :data:`TEX_WIDTH` (4096)-wide texture, entry i at texel
  ``(i % 4096, i // 4096)``; the height may not exceed :data:`MAX_TEX_HEIGHT` (4096, the portable
  limit this viewer designs for), so a texture holds at most 16.7 M entries.

Data are fetched, not embedded: a static export works from any HTTP server
(``python -m http.server`` in the folder), but not from ``file://``, where browsers refuse
``fetch`` (the page then says so). Binary beats base64 here: 33 % smaller, no decode time, and
a UBO2014 material at τ = (885, 64, 64) is tens of MB.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import threading
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..._atomic import remove_stale_parts, temporary_dir
from ..._json import json_default
from ...errors import BTFInputError, FileFormatError, SparseBTFError
from ...runtime.decoder import NO_BOUND
from ...runtime.lod import MIN_FRACTION
from .highlights import highlight_textures
from .tree import pack_tree

if TYPE_CHECKING:
    from ...runtime import AdaptiveRuntimeBTF, RuntimeBTF

__all__ = [
    "HEADLESS_CHROMIUM_FLAGS",
    "MAX_TEX_HEIGHT",
    "TEX_WIDTH",
    "ViewerBundle",
    "ViewerServer",
    "build_bundle",
    "export",
    "host_allowed",
    "host_names",
    "pack_textures",
    "serve",
]

#: Width of every data texture (the shader's ``SB_TEX_WIDTH``).
TEX_WIDTH = 4096
#: Largest texture height the viewer produces: 4096, a size every WebGL2 desktop GPU and
#: SwiftShader (8192) accept (WebGL2 itself only guarantees 2048).
MAX_TEX_HEIGHT = 4096
#: Format tag of ``manifest.json``.
MANIFEST_FORMAT = "sparsebtf-webgl"
#: Names of the static files of the page.
STATIC_FILES = ("index.html", "viewer.js")
SHADER_FILES = ("sparsebtf_lookup.glsl", "viewer_scene.glsl")
#: Flags that give headless Debian Chromium WebGL2 on SwiftShader without touching the network
#: (``shared/specs/rendering-notes.md``); the viewer's tests and benchmark launch it with them.
HEADLESS_CHROMIUM_FLAGS = (
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
    "--hide-scrollbars",
)
_CHANNELS = ("Y", "U", "V")
_ALIGN = 16
_TYPES = {"R32F": ("<f4", 1), "R32UI": ("<u4", 1), "R32I": ("<i4", 1), "RGBA32I": ("<i4", 4),
          "RGBA32F": ("<f4", 4), "RGB16F": ("<f2", 3),
          "RGBA16F": ("<f2", 4)}  # fmt: skip


def _static(name: str) -> bytes:
    return (resources.files(__package__) / "static" / name).read_bytes()


def _shader(name: str) -> bytes:
    return (resources.files("sparsebtf.rendering") / "shaders" / name).read_bytes()


def _texture(name: str, fmt: str, flat: np.ndarray, where: str) -> tuple[dict[str, Any], bytes]:
    """One texture: ``flat`` (n·channels entries) padded to TEX_WIDTH-wide rows."""
    dtype, comps = _TYPES[fmt]
    flat = np.ascontiguousarray(flat, dtype=dtype).ravel()
    n = flat.size // comps
    height = max(1, -(-n // TEX_WIDTH))
    if height > MAX_TEX_HEIGHT:
        raise BTFInputError(
            f"{where}: texture {name} needs {n} texels = {TEX_WIDTH}x{height}, above the "
            f"{TEX_WIDTH}x{MAX_TEX_HEIGHT} limit of the viewer; lower tau (e.g. --tau 0.5) or "
            "crop the material"
        )
    padded = np.zeros(TEX_WIDTH * height * comps, dtype=dtype)
    padded[: flat.size] = flat
    return {"format": fmt, "width": TEX_WIDTH, "height": height, "entries": n}, padded.tobytes()


def pack_textures(
    arrays: dict[str, np.ndarray], meta: dict[str, Any], where: str = "coded BTF"
) -> tuple[dict[str, Any], bytes]:
    """Lay :meth:`RuntimeBTF.arrays` out as the shader's textures and uniforms.

    Returns the manifest part ``{"textures": {...}, "uniforms": {...}, "tau_max": [...],
    "has_neighbours": bool}`` and the binary holding every texture (offsets in the manifest).
    With ``meta["adaptive"]`` (:meth:`AdaptiveRuntimeBTF.arrays` and its ``flat_meta``) the
    points are the tree's nodes, and the texture ``sb_tree``, the uniform ``sb_adaptive``,
    each node's class in ``sb_points`` and the manifest's ``adaptive`` entry are added
    (:mod:`.tree`); a fixed-size material's part is unchanged. With the arrays of a highlight
    store (``RuntimeBTF.arrays()``'s ``highlight_*``) the textures ``sb_hlOffsets``, ``sb_hlKeys``,
    ``sb_hlRgb``, the uniform ``sb_highlights`` and the manifest's ``highlights`` entry count
    are added, with its lobes (``highlight_lobes``) the texture ``sb_hlLobes``, the uniform
    ``sb_lobes`` and the manifest's ``lobes`` count (:mod:`.highlights`); without them nothing
    changes.
    Raises :class:`~sparsebtf.errors.BTFInputError` naming the channel or texture when an
    array is missing or a texture would exceed :data:`MAX_TEX_HEIGHT` rows.
    """
    missing = [
        f"{n}_{c}"
        for c in _CHANNELS
        for n in (
            "membership",
            "offsets",
            "values",
            "locations",
            "dict1",
            "dict2",
            "dict3",
            "dict4",
        )
        if f"{n}_{c}" not in arrays
    ]
    missing += [
        n for n in ("lights_xyz", "views_xyz", "mean", "std", "yuv_to_rgb") if n not in arrays
    ]
    if missing:
        raise BTFInputError(
            f"{where}: the viewer needs Y, U and V codes and the renderer arrays; missing "
            f"{', '.join(missing)}"
        )
    n_points = int(arrays["membership_Y"].shape[0])
    n_l, n_v = int(arrays["lights_xyz"].shape[0]), int(arrays["views_xyz"].shape[0])
    sizes = [int(arrays[f"dict{n}_Y"].shape[1]) for n in (1, 2, 3, 4)]
    if sizes[:2] != [int(meta["patch"])] * 2:  # the shader's stride of the spatial modes
        raise BTFInputError(f"{where}: spatial dictionaries of {sizes[0]}x{sizes[1]} rows, "
                            f"expected the patch {meta['patch']}")  # fmt: skip
    adaptive = bool(meta.get("adaptive"))
    if adaptive:
        cells, classes, tree_uniforms, tree_part = pack_tree(arrays, meta, n_points, where)

    # coefficient values / locations and per-point records (start, count, dictionary, 0)
    values, locations, points, dict_parts, dict_base = [], [], [], [], []
    vbase = dbase = 0
    tau_max = []
    for c in _CHANNELS:
        off = arrays[f"offsets_{c}"].astype(np.int64)
        memb = arrays[f"membership_{c}"].astype(np.int64)
        if memb.shape[0] != n_points or off.shape[0] != n_points + 1:
            raise BTFInputError(f"{where}: channel {c} has {memb.shape[0]} points, Y {n_points}")
        counts = np.diff(off)
        tau_max.append(int(counts.max(initial=0)))
        rec = np.zeros((n_points, 4), dtype=np.int64)
        rec[:, 0] = off[:-1] + vbase
        rec[:, 1] = counts
        rec[:, 2] = memb
        if adaptive:
            rec[:, 3] = classes
        points.append(rec)
        values.append(arrays[f"values_{c}"].astype(np.float32))
        locations.append(arrays[f"locations_{c}"].astype(np.uint32))
        vbase += int(off[-1])
        bases = []
        for n in (1, 2, 3, 4):
            d = arrays[f"dict{n}_{c}"]
            if d.ndim != 3 or int(d.shape[1]) != sizes[n - 1]:
                raise BTFInputError(f"{where}: channel {c} dict{n} has shape {d.shape}")
            bases.append(dbase)
            dict_parts.append(d.astype(np.float32).ravel())
            dbase += d.size
        dict_base.append(bases)
    if vbase >= 2**31 or dbase >= 2**31:
        raise BTFInputError(f"{where}: {vbase} coefficients exceed the shader's int32 offsets")
    mean = arrays["mean"].astype(np.float32)
    std = arrays["std"].astype(np.float32)
    if mean.shape != std.shape or mean.shape[1:] != (n_l, n_v) or mean.shape[0] not in (1, 3):
        raise BTFInputError(
            f"{where}: statistics of shape {mean.shape}, expected (S, {n_l}, {n_v})"
        )
    if "bound" in arrays:
        bound = arrays["bound"].astype(np.float32)
        if bound.shape != (n_l, n_v):
            raise BTFInputError(f"{where}: bound of shape {bound.shape}, expected ({n_l}, {n_v})")
    else:  # no clamp
        bound = np.full((n_l, n_v), NO_BOUND, dtype=np.float32)
    dirs = np.zeros((n_l + n_v, 4), dtype=np.float32)
    dirs[:n_l, :3] = arrays["lights_xyz"]
    dirs[n_l:, :3] = arrays["views_xyz"]

    spec: list[tuple[str, str, np.ndarray]] = [
        ("sb_values", "R32F", np.concatenate(values)),
        ("sb_locations", "R32UI", np.concatenate(locations)),
        ("sb_points", "RGBA32I", np.concatenate(points)),
        ("sb_dicts", "R32F", np.concatenate(dict_parts)),
        ("sb_stats", "R32F", np.concatenate([mean.ravel(), std.ravel(), bound.ravel()])),
        ("sb_dirs", "RGBA32F", dirs),
    ]
    has_neigh = "neighbours_lights" in arrays and "neighbours_views" in arrays
    if has_neigh:
        nl, nv = arrays["neighbours_lights"], arrays["neighbours_views"]
        if nl.shape != (64, 256, 8) or nv.shape != (64, 256, 8):
            raise BTFInputError(
                f"{where}: neighbour tables of shape {nl.shape}/{nv.shape}, the shader reads "
                "(64, 256, 8)"
            )
        spec.append(("sb_neigh", "R32I", np.concatenate([nl.ravel(), nv.ravel()])))
    if adaptive:
        spec.append(("sb_tree", "R32I", cells))
    hl_spec, hl_uniforms, hl_part = highlight_textures(arrays, meta, n_points, n_l, n_v, where)
    spec += hl_spec

    textures: dict[str, Any] = {}
    chunks: list[bytes] = []
    offset = 0
    for name, fmt, flat in spec:
        info, raw = _texture(name, fmt, flat, where)
        info["offset"] = offset
        textures[name] = info
        chunks.append(raw)
        offset += len(raw)
        pad = -offset % _ALIGN
        chunks.append(b"\0" * pad)
        offset += pad

    patch = int(meta["patch"])
    uniforms = {
        "sb_size": [int(meta["height"]), int(meta["width"]), patch, int(meta["height"]) // patch],
        "sb_counts": [n_points, n_l, n_v, int(mean.shape[0])],
        "sb_dictBase": dict_base,
        "sb_dictSize": sizes,
        "sb_stdBase": int(mean.size),
        "sb_boundBase": int(2 * mean.size),
        "sb_yuvToRgb": arrays["yuv_to_rgb"].astype(np.float64).tolist(),
        "sb_eps": float(meta["eps"]),
        "sb_lodMin": MIN_FRACTION,
    }
    part: dict[str, Any] = {
        "textures": textures,
        "uniforms": uniforms,
        "tau_max": tau_max,
        "has_neighbours": has_neigh,
    }
    if adaptive:
        uniforms.update(tree_uniforms)
        part["adaptive"] = tree_part
    uniforms.update(hl_uniforms)
    part.update(hl_part)
    return part, b"".join(chunks)


@dataclass
class ViewerBundle:
    """Everything the page loads: ``manifest`` (JSON), ``data`` (texture binary), static files."""

    manifest: dict[str, Any]
    data: bytes

    def files(self) -> dict[str, bytes]:
        """File name → content of the complete static page."""
        out = {name: _static(name) for name in STATIC_FILES}
        out.update({name: _shader(name) for name in SHADER_FILES})
        out["manifest.json"] = json.dumps(self.manifest, indent=1).encode()
        out[self.manifest["data"]] = self.data
        return out


def _json_meta(meta: dict[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(meta, default=json_default))


def build_bundle(rt: RuntimeBTF | AdaptiveRuntimeBTF, neighbours: bool = True) -> ViewerBundle:
    """The page's manifest and texture binary for a :class:`~sparsebtf.runtime.RuntimeBTF`,
    or an :class:`~sparsebtf.runtime.AdaptiveRuntimeBTF` (adaptive patch sizes: the nodes of
    its tree are the points, :meth:`~sparsebtf.runtime.AdaptiveRuntimeBTF.arrays`).

    ``neighbours`` adds the candidate tables (``runtime.angular.neighbour_table``) so that the
    shader ranks 8 candidates per direction instead of scanning all of them. A material with
    a highlight store (``coded.highlights`` with entries or lobes) carries it (:mod:`.highlights`).
    """
    from ...runtime.adaptive import AdaptiveRuntimeBTF

    meta = rt.flat_meta if isinstance(rt, AdaptiveRuntimeBTF) else rt.meta
    where = str(meta.get("name", "coded BTF"))
    transform = meta.get("transform", "log_yuv")
    if transform != "log_yuv":
        raise BTFInputError(
            f"{where}: the viewer decodes log-YUV codes, this file uses {transform}"
        )
    arrays = rt.arrays(neighbours=neighbours)  # with a highlight store, its arrays too
    if isinstance(rt, AdaptiveRuntimeBTF):  # the whole tree's counts, not the largest size's
        meta = {**meta, "nnz": {c: int(arrays[f"values_{c}"].size) for c in _CHANNELS},
                "tau": {str(p): layer.tau for p, layer in rt.layers.items()}}  # fmt: skip
    part, data = pack_textures(arrays, meta, where)
    manifest = {
        "format": MANIFEST_FORMAT,
        "version": 1,
        "data": "data.bin",
        "bytes": len(data),
        "shaders": {"lookup": SHADER_FILES[0], "scene": SHADER_FILES[1]},
        "meta": _json_meta(meta),
        **part,
    }
    return ViewerBundle(manifest, data)


def _is_export(path: Path) -> bool:
    try:
        return json.loads((path / "manifest.json").read_text()).get("format") == MANIFEST_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def export(bundle: ViewerBundle, out_dir: str | os.PathLike[str]) -> Path:
    """Write the static page and its data into ``out_dir`` atomically.

    The files go to a temporary folder beside ``out_dir``, which is then renamed onto it; an
    earlier export in ``out_dir`` is replaced, any other non-empty folder is refused.
    Serve the folder over HTTP (``python -m http.server``): browsers refuse ``fetch`` from
    ``file://``.
    """
    target = Path(out_dir)
    if target.exists() and not target.is_dir():
        raise FileFormatError(f"{target}: exists and is not a folder")
    if target.is_dir() and any(target.iterdir()) and not _is_export(target):
        raise FileFormatError(
            f"{target}: folder is not empty and holds no earlier viewer export; choose another"
        )
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_parts(target)
    tmp = temporary_dir(target)  # the user's umask, not mkdtemp's 0700: it becomes the export
    old: Path | None = None
    try:
        for name, content in bundle.files().items():
            (tmp / name).write_bytes(content)
        if target.exists():
            old = temporary_dir(target, ".old")
            os.replace(target, old / "x")
        os.replace(tmp, target)
    except BaseException:
        if old is not None and not target.exists():
            os.replace(old / "x", target)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    return target


_CONTENT_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".json": "application/json",
    ".glsl": "text/plain; charset=utf-8",
    ".bin": "application/octet-stream",
}


_LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})


def host_names(host: str, bound: str) -> frozenset[str]:
    """The names a request's ``Host`` may give for a server started with ``host`` and bound
    to the address ``bound`` (lower case, IPv6 without brackets).

    The address as given and as bound; ``localhost``, ``127.0.0.1`` and ``::1`` when bound to
    loopback or to every interface; for every interface also this machine's name. Any IP
    literal the connection actually arrived on is accepted besides (:func:`host_allowed`).
    """
    import ipaddress
    import socket

    names = {host.lower().strip("[]"), bound.lower()}
    try:
        ip = ipaddress.ip_address(bound)
    except ValueError:
        return frozenset(names)
    if ip.is_loopback or ip.is_unspecified:
        names |= _LOOPBACK_NAMES
    if ip.is_unspecified:
        names |= {socket.gethostname().lower(), socket.getfqdn().lower()}
    return frozenset(names)


def host_allowed(header: str | None, names: frozenset[str], port: int, local_ip: str) -> bool:
    """Whether a request's ``Host`` header names this server: one of ``names`` (or the IP
    ``local_ip`` the connection arrived on) and ``port`` (80 when the header gives none).

    A page of another site that a DNS rebinding points at this machine sends its own name
    here, so the viewer answers it 403 (the rebinding defence of every local web server).
    """
    if not header:
        return False
    h = header.strip().lower()
    if h.startswith("["):  # [IPv6]:port
        name, _, rest = h[1:].partition("]")
        if rest and not rest.startswith(":"):
            return False
        given = rest[1:] if rest else "80"
    else:
        name, sep, given = h.rpartition(":")
        if not sep:
            name, given = h, "80"
    if not given.isdigit() or int(given) != port:
        return False
    return name in names or name == local_ip.lower()


class ViewerServer:
    """The page served from memory on 127.0.0.1 in a background thread.

    Use as a context manager, or call :meth:`close`. ``port=0`` picks a free port; the
    address is :attr:`url`. Only requests whose ``Host`` is the address served on are
    answered (:func:`host_allowed`: ``localhost`` and ``127.0.0.1`` too on loopback); others
    get 403 with a one-line body.
    """

    def __init__(self, bundle: ViewerBundle, host: str = "127.0.0.1", port: int = 0) -> None:
        files = {"/" + k: v for k, v in bundle.files().items()}
        files["/"] = files["/index.html"]
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                local_ip = self.connection.getsockname()[0]
                if not host_allowed(self.headers.get("Host"), server.names, server.port,
                                    local_ip):  # fmt: skip
                    body = f"403: this viewer answers requests for {server.url} only\n".encode()
                    self.send_response(403)
                    self.send_header("Content-Type", "text/plain; charset=utf-8")
                    self.send_header("Content-Length", str(len(body)))
                    self.end_headers()
                    with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                        self.wfile.write(body)
                    return
                path = self.path.split("?", 1)[0]
                body = files.get(path)
                if body is None:
                    self.send_error(404, f"no file {path}")
                    return
                self.send_response(200)
                ctype = _CONTENT_TYPES.get(Path(path).suffix, "text/html; charset=utf-8")
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                    self.wfile.write(body)

            def log_message(self, format: str, *args: Any) -> None:
                pass

        try:
            self._httpd = ThreadingHTTPServer((host, port), Handler)
        except OSError as e:
            raise SparseBTFError(f"cannot serve the viewer on {host}:{port}: {e}") from None
        self._httpd.daemon_threads = True
        self.host, self.port = self._httpd.server_address[:2]
        self.url = f"http://{self.host}:{self.port}/"
        self.names = host_names(host, str(self.host))
        self._thread = threading.Thread(target=self._httpd.serve_forever, daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop serving and release the port."""
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5)

    def __enter__(self) -> ViewerServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def serve(bundle: ViewerBundle, host: str = "127.0.0.1", port: int = 0) -> ViewerServer:
    """Start serving ``bundle`` (see :class:`ViewerServer`); returns the running server."""
    return ViewerServer(bundle, host, port)
