"""One run: a skin (an artifact, or an arm whose links each have theirs) on an audio source, opened in one place for
``live``, :func:`sonicskin.listen`, ``record`` and ``check``; :func:`open_source` is the one place a device opens."""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from . import acquire
from .acquire import LOOP_PRIORITY, AudioSource, Link, check_blocksize, realtime_thread
from .dataset import link_wall, other_wall
from .errors import ConfigNotFoundError, UsageError, brief
from .kinds import BASELINE
from .links import ARM_FILE, arm_urdf, load_arm
from .live import LiveLoop, run_loops
from .rig import Rig
from .ros2 import open_buses
from .rosbag import McapEventWriter, Publisher
from .runtime import SkinRuntime
from .sim import Scenario, Simulator, Timeline, build_timeline
from .sim.scenario import session_chirps
from .view import ViewServer, parse_view_port, view_loops

__all__ = ["SIM", "simulated", "arm_file_of", "load_config", "open_source", "live_scenario", "Run", "open_run"]

SIM = "sim"  #: the simulated device's name (``--device sim``, ``device="sim"``; ``None`` too)


def simulated(device) -> bool:
    """``device`` is the simulated device (``None`` or ``"sim"``), not an audio interface's name or index."""
    return device is None or device == SIM


def arm_file_of(path) -> Path | None:
    """The arm file a path names (a ``.yaml`` with ``links:``, or a folder holding ``arm.yaml``), else ``None``."""
    p = Path(path)
    if p.is_dir() and (p / ARM_FILE).is_file():
        return p / ARM_FILE
    if p.is_file() and p.suffix in (".yaml", ".yml"):
        return p
    return None


def load_config(load: Callable, what):
    """A rig or scenario config; a name that is no config is :class:`ConfigNotFoundError` (a FileNotFoundError)."""
    try:
        return load(what)
    except FileNotFoundError as e:
        raise ConfigNotFoundError(str(e)) from None


def open_source(rig: Rig, device, links: list[Link], *, play: Callable[[Link], tuple[Simulator, Timeline]] | None = None,
                blocksize: int = 1024, realtime: bool = True, drop_every: int | None = None, offset: int = 4321,
                **interface) -> AudioSource:
    """The audio source carrying ``links``: simulated (each link's wall plays ``play(link)``), else the interface ``device``."""
    if simulated(device):
        sims, timelines = zip(*(play(lk) for lk in links))
        return acquire.SimulatedSource(list(sims), list(timelines), blocksize=blocksize, realtime=realtime,
                                       drop_every=drop_every, offset=offset)
    return acquire.SoundDeviceSource(rig, device, links=links, blocksize=blocksize, **interface)


#: the longest session of scripted presses a simulated run plays (its ground truth is built ahead, a chirp a row)
MAX_SCRIPTED_S = 3600.0


def live_scenario(scenario: Scenario, rig: Rig | None = None, duration_s: float | None = None) -> Scenario:
    """What a run plays on a simulated link: the same link (its ``link_seed``), a new person-session of scripted touches,
    with every marker pressed often enough that the session lasts ``duration_s`` (on ``rig``) when it is given."""
    sc = scenario.replace(seed=scenario.seed + 1000, sessions=1)
    if rig is None or duration_s is None:
        return sc
    duration_s = min(duration_s, MAX_SCRIPTED_S)  # longer: the run says the session's length and ends with it
    reps = sc.repeats if sc.train_repeats is None else sc.train_repeats
    while (length := session_chirps(sc, rig)[0] / rig.chirps_per_s) < duration_s:  # the calibration span is fixed
        reps = max(reps + 1, int(np.ceil(reps * duration_s / length)))
        sc = sc.replace(repeats=reps, train_repeats=None)
    return sc


@dataclasses.dataclass(eq=False)
class Run:
    """An opened run: its links, a runtime per link and the one source carrying them; :meth:`loops`, then :meth:`run`, once."""

    links: list[Link]
    runtimes: list[SkinRuntime]
    source: AudioSource
    rig: Rig
    spec: object = None               # the arm or links file it was opened from; None: one artifact
    scenarios: list | None = None     # (name, scenario) per link on the simulated device: how the live page draws them
    live: list[LiveLoop] = dataclasses.field(default_factory=list)  # the loops run() runs
    view: ViewServer | None = None
    mcap: McapEventWriter | None = None
    # real-time scheduling of the audio and processing threads (``source.rt_sched``); what they got: granted
    granted: dict = dataclasses.field(default_factory=dict)
    buses: list[Publisher] = dataclasses.field(default_factory=list)  # the live ROS 2 (DDS) and Foxglove publishers

    @property
    def publishers(self) -> list[Publisher]:
        """Where the run's ROS 2 messages go: the MCAP file and the live buses."""
        return [p for p in (self.mcap, *self.buses) if p is not None]

    @property
    def arm(self) -> bool:
        """Opened from an arm or links file: every event names its link, the summary is keyed by link."""
        return self.spec is not None

    def loops(self, *, emit: Callable[[str], None] | None = None, status: bool = False,
              on_event: Callable | None = None, view: bool | int | str | None = None) -> list[LiveLoop]:
        """One :class:`~sonicskin.live.LiveLoop` per link, every event also to :attr:`publishers`, and with ``view`` the live page."""
        def event(ev) -> None:
            for pub in self.publishers:
                pub.write(ev)
            if on_event is not None:
                on_event(ev)

        self.live = [LiveLoop(rt, self.source, link=lk if self.arm else None, channel=i, emit=emit, status=status,
                               on_event=event) for i, (lk, rt) in enumerate(zip(self.links, self.runtimes))]
        for lp in self.live if self.publishers else ():
            lp.on_chirp = lambda t_s, p, lp=lp: [pub.contact(lp, t_s, p) for pub in self.publishers]
        if view is not None and view is not False:
            try:
                self.view = view_loops(self.live, scenarios=self.scenarios, port=parse_view_port(view),
                                       urdf=arm_urdf(self.spec) if self.arm else None)
            except BaseException:  # e.g. a taken port: the run never starts, so nothing of it is written
                for pub in self.publishers:
                    pub.discard()
                raise
        return self.live

    def run(self, *, duration_s: float | None = None, watchdog_s: float | None = 3.0, stop=None) -> dict:
        """Run the loops (:func:`sonicskin.live.run_loops`); the MCAP file is complete and the page stopped however it ends."""
        length = getattr(self.source, "length_s", None)  # a simulated session ends by itself
        if duration_s is not None and length is not None and duration_s > length and self.live:
            self.live[0].warn(f"the simulated session is {length:.1f} s long (one scripted session of touches per link): "
                              f"the run ends with it, before the {duration_s:g} s asked for")
        with contextlib.ExitStack() as done:  # every publisher closed and the page stopped, whatever ends the run
            for pub in self.publishers:
                done.callback(pub.close)
            if self.view is not None:
                done.callback(self.view.stop)
            t0 = time.time()  # t_s = 0: the stream starts now
            for pub in self.publishers:
                pub.t0_unix_s = t0
                pub.start()
            with self.source:
                if self.source.rt_sched:  # the source's thread asks for itself as it starts; this thread processes
                    for _ in range(100):  # the audio thread's first callback (a device) or start (simulated)
                        if self.source.rt_granted is not None:
                            break
                        time.sleep(0.01)
                    self.granted["audio"] = self.source.rt_granted or "its thread had not started after 1 s"
                    self.granted["processing"], undo = realtime_thread(LOOP_PRIORITY)
                    done.callback(undo)
                    gc.freeze()  # what the run opened is never scanned again by the collector
                    print(f"sonicskin: real-time scheduling: audio thread {self.granted['audio']}; processing thread "
                          f"{self.granted['processing']}", file=sys.stderr, flush=True)
                return self.summary(run_loops(self.live, self.source, duration_s=duration_s, watchdog_s=watchdog_s, stop=stop))

    def summary(self, sums: list[dict]) -> dict:
        """The loops' summaries as ``sonicskin live`` prints them: keyed by link on an arm, else the one loop's."""
        return {lk.name: s for lk, s in zip(self.links, sums)} if self.arm else sums[0]


def open_run(artifact=None, *, links=None, device=SIM, model: str | None = None, scenario=None, rig=None,
             tx: int = 0, rx: int = 0, fast: bool = False, blocksize: int = 1024, drop_every: int | None = None,
             link_artifacts: list | None = None, train: Callable[[Scenario, Rig], Path] | None = None,
             mcap=None, overwrite: bool = False, realtime: bool = False, ros2=None, foxglove=None,
             duration_s: float | None = None) -> Run:
    """Open a skin (an artifact, an arm, or a links file with ``link_artifacts``) on a device (``"sim"``/``None`` or an
    interface), with its outputs (``mcap``, ``ros2``, ``foxglove``) opened here.  ``train(scenario, rig)``: the artifact
    of a simulated link without one.  ``realtime``: what the threads got is :attr:`Run.granted`.  ``duration_s``: a
    simulated session scripts presses for at least that long."""
    check_blocksize(blocksize)
    sim = simulated(device)
    if realtime and fast and sim:
        raise UsageError("--realtime/realtime= schedules a run at the sample rate, --fast/fast= runs as fast as it goes; "
                         "drop one of them")
    given = load_config(Rig.load, rig) if isinstance(rig, (str, Path)) else rig
    spec = links if links is not None else arm_file_of(artifact) if artifact is not None else None
    if links is not None and artifact is not None:
        raise UsageError(f"--artifact {artifact} with --links {links}: an arm's links carry their artifacts (its arm file's "
                         f"`artifact:`, or --link-artifact DIR once per link); drop --artifact")
    if spec is not None and (tx or rx or scenario is not None):
        raise UsageError(f"{spec} is an arm: each link takes its channels and its simulated wall from the arm file (tx:, "
                         f"rx:, scenario:); drop --tx/--rx/--scenario (tx=, rx=, scenario=)")
    if spec is not None:
        the_rig, lks = load_arm(spec, given)
        if sim and any(lk.scenario is None for lk in lks):
            raise UsageError(f"--links {spec} lists links of a real audio interface (no simulated scenario per link); "
                             f"pass --device NAME|INDEX (`sonicskin devices`), or run a simulated arm (`sonicskin info` "
                             f"lists the arms, e.g. --links arm6)")
    else:  # one artifact: an arm of one link (its rig: the given one, else the artifact's own, else jaco to train one)
        the_rig = given if given is not None or artifact is not None else Rig.load("jaco")
        lks = [Link(tx=tx, rx=rx, name="skin", scenario=load_config(Scenario.load, scenario or "stationary") if sim else None,
                    artifact=artifact)]
    pubs: list[Publisher] = []
    for what, v in (("--mcap/mcap=", mcap), ("--ros2/ros2=", ros2), ("--foxglove/foxglove=", foxglove)):
        if v is not None:
            _require_frames(lks, spec, what)
    try:  # opened before the models load: a bad or taken path or port is refused now, a DDS reader has time to match
        if mcap is not None:
            pubs.append(McapEventWriter(mcap, t0_unix_s=time.time(), overwrite=overwrite))
        pubs += open_buses(ros2, foxglove)
        for pub in pubs:  # every link's topics, and the arm's URDF: /robot_description, /tf_static, set_joint_state
            pub.announce([lk.surface.frame_id for lk in lks], arm_urdf(spec))
        run = _open(spec, lks, the_rig, sim, device, model, link_artifacts, train, blocksize, fast, drop_every,
                    pubs[0] if mcap is not None else None, duration_s)
        run.buses = pubs[mcap is not None:]
        run.source.rt_sched = bool(realtime)
        return run
    except BaseException:
        for pub in pubs:
            pub.discard()  # nothing recorded: no file left behind
        raise


def _open(spec, lks, the_rig, sim, device, model, link_artifacts, train, blocksize, fast, drop_every, writer, duration_s) -> Run:
    arts = _artifacts(spec, lks, the_rig, link_artifacts, train if sim else None)
    runtimes = [SkinRuntime(Path(art), model or BASELINE, rig=lk.rig or the_rig) for lk, art in zip(lks, arts)]
    the_rig = the_rig or runtimes[0].rig
    for lk, rt in zip(lks if spec else [], runtimes):
        _check_trained_for(spec, lk, rt, lks)
    if not sim:
        return Run(lks, runtimes, open_source(the_rig, device, lks, blocksize=blocksize), the_rig, spec, mcap=writer)
    for lk, rt in zip(lks, runtimes):
        layout = lk.scenario.make_layout()
        if rt.layout != layout:
            raise UsageError(f"{f'link {lk.name!r}: ' if spec else ''}the artifact knows {len(rt.layout)} markers but "
                             f"scenario {lk.scenario.name!r} has {len(layout)} in another layout; " +
                             (f"train it on this link (`sonicskin fit-svm --links {spec} ...`)" if spec else
                              "run it on the scenario it was trained on (--scenario, scenario=), or train on this one"))

    played = {lk.name: live_scenario(lk.scenario, lk.rig or the_rig, duration_s) for lk in lks}

    def play(lk: Link) -> tuple[Simulator, Timeline]:
        sc, link_rig = played[lk.name], lk.rig or the_rig
        return Simulator(sc, link_rig), build_timeline(sc, link_rig)

    source = open_source(the_rig, device, lks, play=play, blocksize=blocksize, realtime=not fast, drop_every=drop_every)
    return Run(lks, runtimes, source, the_rig, spec, list(played.items()), mcap=writer)


def _check_trained_for(spec, lk: Link, rt: SkinRuntime, links: list[Link]) -> None:
    """An arm's link runs an artifact trained for it: one for another link or wall is refused, one that records neither warned."""
    tr = rt.meta["training"]
    rec, wall = tr.get("link") if isinstance(tr.get("link"), dict) else {}, tr.get("wall")
    fix = (f"give each link its own artifact (--link-artifact DIR once per link, in the order "
           f"{', '.join(x.name for x in links)}), or train this link: `sonicskin fit-svm --links {spec} --data DIR --out ART`")
    if not rec and not isinstance(wall, dict):
        return warnings.warn(f"link {lk.name!r}: {rt.folder} does not record which link and wall it was trained for (an "
                             f"artifact from before sonicskin recorded them), so it is not checked against this link; {fix}",
                             stacklevel=4)
    other = [f"link {brief(rec['name'])}"] if rec.get("name") not in (None, lk.name) else []
    other += [f"frame {brief(rec['frame'])}"] if rec.get("frame") not in (None, lk.frame) else []
    other += [w for w in [lk.scenario and other_wall(wall, link_wall(lk.scenario, rt.rig, rt.layout), "this link's")] if w]
    if other:
        raise UsageError(f"link {lk.name!r}: {rt.folder} was trained for {' and '.join(other)}, not this link; {fix}")


def _require_frames(links: list[Link], spec, what: str) -> None:
    """ROS 2 messages hold each touch in its link's frame: one line naming the links without a surface, and the fix."""
    if spec is None:
        raise UsageError(f"{what} writes each touch in its link's frame, which an arm file gives its links: run an "
                         "arm (--links arm6, or the folder `sonicskin fit-svm --links` wrote, holding arm.yaml)")
    bare = [lk.name for lk in links if lk.surface is None]
    if bare:
        raise UsageError(f"{what} writes each touch in its link's frame, and {spec} places no surface on links "
                         f"{bare}; give them a frame (an arm file's `frame:` with `urdf:`, or `surface:`: "
                         f"docs/robot-frame.md)")


def _artifacts(spec, links: list[Link], rig: Rig, given: list | None, train: Callable | None) -> list[Path]:
    """Each link's artifact folder: ``given`` (one per link), else the link's own, else trained on the spot."""
    if given:
        if len(given) != len(links):
            raise UsageError(f"--links {spec} has {len(links)} links ({', '.join(lk.name for lk in links)}); pass "
                             f"--link-artifact DIR once per link, in that order (got {len(given)})")
        return [Path(x) for x in given]
    arts = []
    for lk in links:
        if lk.artifact is None and not (train is not None and lk.scenario is not None):
            raise UsageError(f"--links {spec}: link {lk.name!r} has no artifact; train one per link on that link's own "
                             f"recordings (`sonicskin fit-svm --links {spec} --data DIR --out ART`, then --links "
                             f"ART/{ARM_FILE}), or pass --link-artifact DIR once per link")
        arts.append(Path(lk.artifact) if lk.artifact is not None else Path(train(lk.scenario, lk.rig or rig)))
    return arts
