"""docs/view.png: the live view (sonicskin.view) of two simulated links with a touch on one, shot by headless chromium.

    python tools/view_screenshot.py [OUT.png]

Needs a `chromium` binary (Debian: apt-get install chromium).  The events are scripted (no simulation runs), so the
picture is the same on every machine but for the fonts.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from sonicskin.events import TouchEvent
from sonicskin.sim import Scenario
from sonicskin.view import LinkView, ViewServer

REPO = Path(__file__).resolve().parents[1]


def view_of_two_links() -> ViewServer:
    """A tube (the paper's CFRP link, 31 markers) and an aluminium plate (36 markers); a 4.2 N press on the tube."""
    tube = LinkView.from_scenario("forearm", Scenario.load("stationary"))
    plate = LinkView.from_scenario("hand-plate", Scenario.load("plate-aluminium"))
    view = ViewServer([tube, plate])

    def ev(t, kind, link, loc, f):
        lk = tube if link == "forearm" else plate
        x, y = lk.layout.coords([loc])[0]
        return TouchEvent(t, kind, loc, float(x) + 0.2, float(y) - 0.1, f, 0.93, "svm", 0.8, link=link)

    for e in (ev(41.60, "touch", "hand-plate", 14, 3.1), ev(41.71, "touch", "hand-plate", 14, 3.4),
              ev(41.81, "release", "hand-plate", 14, 0.0), ev(44.37, "touch", "forearm", 20, 2.2),
              ev(44.48, "touch", "forearm", 20, 3.6), ev(44.59, "touch", "forearm", 20, 4.2)):
        view.push_event(e)
    view.set_status("forearm", {"refreshes": 3, "stretch": -4.1e-4, "reference_age_s": 12.8, "chirps": 412,
                                "text": "drift -4.10e-04 (+1.2 K)"})
    view.set_status("hand-plate", {"refreshes": 3, "stretch": 1.2e-4, "reference_age_s": 9.6, "chirps": 412,
                                   "text": "drift +1.20e-04 (-5.0 K)"})
    return view


def main(out: str = str(REPO / "docs" / "view.png")) -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        sys.exit("view_screenshot: no chromium binary; install it (Debian: apt-get install chromium)")
    with view_of_two_links() as view, tempfile.TemporaryDirectory() as profile:
        subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={profile}",
                        "--hide-scrollbars", "--virtual-time-budget=2000", f"--screenshot={Path(out).resolve()}",
                        "--window-size=1280,800", view.url], check=True, capture_output=True, timeout=120)
    print(out)


if __name__ == "__main__":
    main(*sys.argv[1:])
