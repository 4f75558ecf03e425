"""Open report pages in a real headless browser (Debian's ``chromium``) and say what broke.

Used by the tests and by ``repro report --check``.  A page is loaded from disk
(``file://``), with a virtual time budget so that every image has loaded; the page's own
check script (:mod:`repro.report.html_report`) records on ``<body>`` how many images decoded,
how many did not, and how many script errors happened; chromium's log on stderr carries any
console message (a report page logs none, so every console line is a problem).
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

from repro.errors import ConfigError

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "chrome")
#: how long a page may take to load (virtual time, ms) and the process to run (s)
VIRTUAL_TIME_MS = 10_000
TIMEOUT_S = 90
_ATTR = re.compile(r'data-(images-ok|images-failed|script-errors)="(\d+)"')


def find_chromium() -> str | None:
    """The path of a chromium-like browser on PATH, or None."""
    for name in CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


def _chromium(args: list[str]) -> subprocess.CompletedProcess:
    exe = find_chromium()
    if exe is None:
        raise ConfigError("no chromium on PATH: install Debian's package (`apt-get install "
                          "chromium`, or `make browser`) to check reports in a browser")
    base = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            "--force-device-scale-factor=1", "--no-first-run", "--disable-extensions",
            f"--virtual-time-budget={VIRTUAL_TIME_MS}"]
    return subprocess.run(base + args, capture_output=True, text=True, timeout=TIMEOUT_S)


def load_page(page: str | Path) -> dict:
    """Load ``page``; returns ``{"images_ok", "images_failed", "script_errors", "console",
    "checked"}`` (``checked`` False when the page's check script did not run)."""
    page = Path(page).resolve()
    res = _chromium(["--enable-logging=stderr", "--v=0", "--dump-dom", page.as_uri()])
    found = {k.replace("-", "_"): int(v) for k, v in _ATTR.findall(res.stdout)}
    console = [ln for ln in res.stderr.splitlines() if ":CONSOLE" in ln]
    return {"images_ok": found.get("images_ok", 0), "images_failed": found.get("images_failed", 0),
            "script_errors": found.get("script_errors", 0), "console": console,
            "checked": len(found) == 3, "returncode": res.returncode}


def screenshot(page: str | Path, png: str | Path, *, size: tuple[int, int] = (1280, 900)) -> Path:
    """A screenshot of ``page`` at ``size`` (width, height) CSS pixels into ``png``."""
    page, png = Path(page).resolve(), Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    res = _chromium([f"--window-size={size[0]},{size[1]}", f"--screenshot={png}", page.as_uri()])
    if not png.is_file():
        raise ConfigError(f"chromium made no screenshot of {page} (exit {res.returncode}): "
                          f"{res.stderr.strip()[-300:]}")
    return png


def check_report(folder: str | Path) -> list[str]:
    """Problems of every ``*.html`` page in ``folder`` (empty: all pages loaded, every image
    decoded, no script error, no console message)."""
    folder = Path(folder)
    pages = sorted(folder.glob("*.html"))
    if not pages:
        return [f"{folder}: no HTML page"]
    problems = []
    for p in pages:
        r = load_page(p)
        if not r["checked"]:
            problems.append(f"{p.name}: the page's check did not run (exit {r['returncode']})")
            continue
        if r["images_failed"]:
            problems.append(f"{p.name}: {r['images_failed']} image(s) did not decode")
        if r["script_errors"]:
            problems.append(f"{p.name}: {r['script_errors']} script error(s)")
        problems += [f"{p.name}: console: {c}" for c in r["console"]]
    return problems
