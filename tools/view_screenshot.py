"""docs/view.png: the live view (sonicskin.view) of the simulated arm6 with a press on the forearm, shot by headless
chromium at 1280 x 800.

    python tools/view_screenshot.py [OUT.png]

Needs a `chromium` binary (Debian: apt-get install chromium).  The events are scripted (no simulation runs), so the
picture is the same on every machine but for the fonts; tests/test_view.py reads the same page in a browser.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from sonicskin.events import TouchEvent, attach_surface
from sonicskin.links import load_links
from sonicskin.rig import Rig, config_dir
from sonicskin.view import LinkView, ViewServer

REPO = Path(__file__).resolve().parents[1]


def view_of_arm6() -> tuple[ViewServer, list[TouchEvent]]:
    """arm6's six links, each skin in its URDF frame; the hand plate pressed and released, then a 4.2 N press on the
    forearm, still on (the view and the events pushed)."""
    links = {lk.name: lk for lk in load_links("arm6", Rig.load("fast"))}
    view = ViewServer([LinkView.from_scenario(lk.name, lk.scenario, lk.surface) for lk in links.values()],
                      urdf=(config_dir() / "arms" / "arm6.urdf").read_text())

    def ev(t, kind, name, loc, f):
        lk = links[name]
        x, y = lk.scenario.make_layout().coords([loc])[0]
        return attach_surface(TouchEvent(t, kind, loc, float(x) + 0.2, float(y) - 0.1, f, 0.93, "svm", 0.8, link=name),
                              lk.surface)

    events = [ev(41.60, "touch", "hand", 5, 3.1), ev(41.61, "touch", "hand", 5, 3.4), ev(41.63, "release", "hand", 5, 0.0),
              ev(44.37, "touch", "forearm", 5, 2.2), ev(44.38, "touch", "forearm", 5, 3.6), ev(44.40, "touch", "forearm", 5, 4.2)]
    for e in events:
        view.push_event(e)
    for name in links:
        view.set_status(name, {"refreshes": 3, "stretch": -4.1e-4, "reference_age_s": 12.8, "chirps": 3320,
                               "text": "drift -4.10e-04 (+1.2 K)"})
    return view, events


def main(out: str = str(REPO / "docs" / "view.png")) -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        sys.exit("view_screenshot: no chromium binary; install it (Debian: apt-get install chromium)")
    view, _ = view_of_arm6()
    with view, tempfile.TemporaryDirectory() as profile:
        subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={profile}",
                        "--hide-scrollbars", "--virtual-time-budget=2000", f"--screenshot={Path(out).resolve()}",
                        "--window-size=1280,800", view.url], check=True, capture_output=True, timeout=120)
    print(out)


if __name__ == "__main__":
    main(*sys.argv[1:])
