"""The Datasette plugin in a real browser: ingest the bundled example models, serve the database
with ``datasette``, take headless Chromium screenshots of a model's page and of the gallery, and fetch the GLB link
the model's page offers.

Run: ``python examples/datasette_check.py [--db out/browse.db] [--out out/datasette_model.png]``.
It prints the page's URL, the GLB link, what the link served (status, content type, file name,
bytes, the mesh's vertices and faces as trimesh reads it) and where the screenshots are (``OUT`` and ``OUT_gallery.png``); exit 1
when a check fails. The database is made when missing (an ingest of ``examples/models`` at 8
bits per surfel, a minute or two of CPU). ``datasette`` loads the plugin by its entry point when
surfidx is installed (``pip install 'surfidx[browse]'``); from a source tree that is not
installed, the server is started with the plugin registered by hand.
"""

from __future__ import annotations

import argparse
import html
import importlib.metadata
import io
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

import surfidx

HERE = Path(__file__).resolve().parent
MODELS = HERE / "models"
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--hide-scrollbars")
#: The server is given this long to answer (a guard against a hang, not a measurement).
STARTUP_S = 60
#: Chromium's page load budget (virtual time: the thumbnails are loaded before the shot).
PAGE_BUDGET_MS = 8000


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _plugin_installed() -> bool:
    eps = importlib.metadata.entry_points(group="datasette")
    return any(ep.value == "surfidx.browse" for ep in eps)


def _server(db: Path, metadata: Path, port: int) -> subprocess.Popen:
    args = [str(db), "--metadata", str(metadata), "-h", "127.0.0.1", "-p", str(port)]
    if _plugin_installed():
        exe = shutil.which("datasette") or str(Path(sys.executable).parent / "datasette")
        cmd = [exe, *args]
    else:
        boot = ("import sys\nfrom datasette.plugins import pm\nimport surfidx.browse as p\n"
                "pm.register(p, name='surfidx')\nfrom datasette.cli import cli\n"
                "sys.argv = ['datasette', 'serve', *sys.argv[1:]]\ncli()\n")
        cmd = [sys.executable, "-c", boot, *args]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def _get(url: str):
    """``(status, headers, body)`` of a GET."""
    try:
        with urllib.request.urlopen(url, timeout=120) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), exc.read()


def _wait(url: str, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + STARTUP_S
    while True:
        try:
            _get(url)
            return
        except OSError:
            if proc.poll() is not None:
                raise SystemExit(f"datasette exited: {proc.stderr.read()[-2000:]}")
            if time.monotonic() > deadline:
                raise SystemExit(f"datasette did not answer {url} within {STARTUP_S} s")
            time.sleep(0.3)


def make_db(path: Path) -> None:
    """Ingest ``examples/models`` into ``path`` (when it holds no model yet)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with surfidx.Database.open(path) as db:
        if db.count() == 0:
            db.ingest([MODELS], bits_per_surfel=8, workers=1)


def screenshot(url: str, out: Path, *, size=(1600, 700)) -> None:
    """A headless Chromium screenshot of ``url`` as the PNG ``out``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="surfidx-chromium-") as profile:
        subprocess.run(["/usr/bin/chromium", *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                        f"--window-size={size[0]},{size[1]}",
                        f"--virtual-time-budget={PAGE_BUDGET_MS}",
                        f"--screenshot={out}", url],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                       timeout=180)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", type=Path, default=Path("out/browse.db"))
    ap.add_argument("--out", type=Path, default=Path("out/datasette_model.png"))
    ap.add_argument("--model", default="armadillo", help="The model whose page is shown.")
    args = ap.parse_args()
    make_db(args.db)
    with surfidx.Database.open(args.db, readonly=True) as db:
        mid = db.resolve(args.model)
    name = args.db.stem
    port = _free_port()
    with tempfile.TemporaryDirectory() as tmp:
        meta = Path(tmp) / "meta.json"
        subprocess.run([sys.executable, "-m", "surfidx", "datasette-metadata", "-o", str(meta),
                        "-q"], check=True)
        proc = _server(args.db, meta, port)
        try:
            base = f"http://127.0.0.1:{port}"
            page = f"{base}/{name}/models/{mid}"
            _wait(page, proc)
            status, _, body = _get(page)
            text = body.decode("utf-8", "replace")
            links = re.findall(r'href="([^"]+\.glb)" download', text)
            print(f"model page {page}: HTTP {status}, GLB links {links}")
            screenshot(page, args.out)
            print(f"screenshot {args.out} ({args.out.stat().st_size:,} bytes)")
            gallery = args.out.with_name(args.out.stem + "_gallery.png")
            screenshot(f"{base}/{name}/model_gallery", gallery)
            print(f"screenshot {gallery} (model_gallery, {gallery.stat().st_size:,} bytes)")
            ok = status == 200 and len(links) == 1
            if links:
                status, headers, glb = _get(base + html.unescape(links[0]))
                headers = {k.lower(): v for k, v in headers.items()}
                print(f"GLB {links[0]}: HTTP {status}, {headers.get('content-type')}, "
                      f"{headers.get('content-disposition')}, {len(glb):,} bytes")
                ok &= status == 200 and glb[:4] == b"glTF"
                import trimesh

                mesh = trimesh.load(io.BytesIO(glb), file_type="glb", force="mesh")
                print(f"  read back by trimesh: {len(mesh.vertices):,} vertices, "
                      f"{len(mesh.faces):,} faces")
                status, _, _ = _get(f"{base}/-/surfidx/{name}/{mid}.glb?bits=2")
                print(f"GLB at 2 bits/surfel: HTTP {status}")
                status, _, body = _get(f"{base}/-/surfidx/{name}/999999.glb")
                print(f"unknown id: HTTP {status}")
                ok &= status == 404
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    print("ok" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
