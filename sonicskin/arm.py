"""A whole arm at once: every link of a links or arm file (:mod:`sonicskin.links`) with its model, on one audio
interface or on the simulated arm, one :class:`~sonicskin.live.LiveLoop` per link over one source.

``sonicskin live --links FILE`` and :func:`sonicskin.listen` (given an arm file) both open the arm here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from .errors import SonicskinError, UsageError
from .links import ARM_FILE, load_arm

__all__ = ["ArmRun", "open_arm", "arm_file_of"]


def arm_file_of(path) -> Path | None:
    """The arm file a path names: a ``.yaml`` file with ``links:``, or a folder holding ``arm.yaml`` (what ``fit-svm
    --links`` writes); ``None`` for anything else (a single-link artifact folder)."""
    p = Path(path)
    if p.is_dir() and (p / ARM_FILE).is_file():
        return p / ARM_FILE
    if p.is_file() and p.suffix in (".yaml", ".yml"):
        return p
    return None


@dataclasses.dataclass
class ArmRun:
    """The opened arm: its links, one runtime per link, the audio source that carries all of them."""

    links: list
    runtimes: list
    source: object
    rig: object
    spec: object = None        # the arm or links file it was opened from (for messages)
    simulated: bool = False    # the simulated arm (each link's scenario plays on its channel)

    @property
    def scenarios(self) -> list | None:
        """``(name, scenario)`` per link on the simulated arm (how the live view draws them), else ``None``."""
        return [(lk.name, lk.scenario) for lk in self.links] if self.simulated else None

    def require_frames(self, what: str) -> None:
        """``what`` (``--mcap``, ``mcap=``) writes touches in the links' frames: one line naming the links without
        a surface, and how to give them one."""
        bare = [lk.name for lk in self.links if lk.surface is None]
        if bare:
            raise UsageError(f"{what} writes each touch in its link's frame, and {self.spec} places no surface on links "
                             f"{bare}; give them a frame (an arm file's `frame:` with `urdf:`, or `surface:`: "
                             f"docs/robot-frame.md)")

    def loops(self, **kw) -> list:
        """One :class:`~sonicskin.live.LiveLoop` per link (``kw`` as LiveLoop's: emit, status, on_event, ...)."""
        from .live import LiveLoop

        return [LiveLoop(rt, self.source, link=lk, channel=i, **kw) for i, (lk, rt) in enumerate(zip(self.links, self.runtimes))]


def open_arm(spec, *, device: str | int | None = "sim", model: str = "svm", rig=None, fast: bool = False,
             blocksize: int = 1024, drop_every: int | None = None, link_artifacts: list | None = None,
             train: Callable | None = None) -> ArmRun:
    """Load the links of ``spec`` (a name or path), each link's artifact, and the source: the simulated arm
    (``device`` ``"sim"`` or ``None``: every link's scenario on its own channel, a new session of scripted touches) or a
    real interface.  ``link_artifacts``: one per link, in order (default: the arm file's ``artifact:``).  ``train``:
    called as ``train(scenario, rig)`` for a simulated link without an artifact (the CLI trains one on the spot);
    without it such a link is a one-line error."""
    from .acquire import SimulatedSource, SoundDeviceSource
    from .runtime import SkinRuntime

    sim = device is None or device == "sim"
    the_rig, links = load_arm(spec, rig)
    if sim and not all(lk.scenario is not None for lk in links):
        raise UsageError(f"--links {spec} lists links of a real audio interface (no simulated scenario per link); "
                         f"pass --device NAME|INDEX (`sonicskin devices`), or run a simulated arm (`sonicskin info` "
                         f"lists the arms, e.g. --links arm6)")
    arts = _artifacts(spec, links, the_rig, link_artifacts, train if sim else None)
    runtimes = [SkinRuntime(Path(art), model, rig=lk.rig or the_rig) for lk, art in zip(links, arts)]
    if not sim:
        return ArmRun(links, runtimes, SoundDeviceSource(the_rig, device, links=links, blocksize=blocksize), the_rig,
                      spec, simulated=False)
    from .sim import Simulator, build_timeline

    sims, tls = [], []
    for lk, rt in zip(links, runtimes):
        if rt.layout != lk.scenario.make_layout():
            raise UsageError(f"link {lk.name!r}: its artifact knows {len(rt.layout)} markers in another layout than its "
                             f"scenario's {len(lk.scenario.make_layout())}; train it on this link "
                             f"(`sonicskin fit-svm --links {spec} ...`)")
        live_sc = lk.scenario.replace(seed=lk.scenario.seed + 1000, sessions=1)  # the same link, a new person-session
        sims.append(Simulator(live_sc, lk.rig or the_rig))
        tls.append(build_timeline(live_sc, lk.rig or the_rig))
    return ArmRun(links, runtimes, SimulatedSource(sims, tls, realtime=not fast, drop_every=drop_every,
                                                   blocksize=blocksize), the_rig, spec, simulated=True)


def _artifacts(spec, links, rig, given, train) -> list[Path]:
    if given:
        if len(given) != len(links):
            raise UsageError(f"--links {spec} has {len(links)} links ({', '.join(lk.name for lk in links)}); pass "
                             f"--link-artifact DIR once per link, in that order (got {len(given)})")
        arts = [Path(x) for x in given]
    else:
        arts = []
        for lk in links:
            if lk.artifact is not None:
                arts.append(Path(lk.artifact))
            elif train is not None and lk.scenario is not None:
                arts.append(Path(train(lk.scenario, lk.rig or rig)))
            else:
                raise UsageError(f"--links {spec}: link {lk.name!r} has no artifact; train one per link on that "
                                 f"link's own recordings (`sonicskin fit-svm --links {spec} --data DIR --out ART`, then "
                                 f"--links ART/{ARM_FILE}), or pass --link-artifact DIR once per link")
    for lk, art in zip(links, arts):
        if not (Path(art) / "skin.json").is_file():
            raise SonicskinError(f"{art} (link {lk.name!r}) is not a sonicskin artifact (no skin.json there); train one "
                                 f"per link on that link's own recordings (`sonicskin fit-svm --links`)")
    return arts
