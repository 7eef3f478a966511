"""``sonicskin record``: the guided one-shot training session on a robot (paper Sec. III-A).

The recorder prompts hands off, hands off while the robot moves, then each location in turn, writing one part per
prompt (Ctrl-C loses at most the prompt in progress); a chirp's label is the prompt showing when it was received.
On the simulated device a simulated person follows the prompts (:func:`person_timeline`)."""

from __future__ import annotations

import contextlib
import csv
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from .acquire import AudioSource, Link, blocks
from .dataset import COLUMNS, Dataset, DatasetWriter
from .dsp import rig_chirp
from .errors import check_memory, is_number
from .fit import build_svm_artifact
from .live import Framer
from .rig import Layout, Rig
from .selection import press_ids
from .session import SIM, open_source, simulated
from .sim import Simulator, generate
from .sim.finger import make_subjects, press_profile
from .sim.scenario import SEGMENTS, Timeline, _motion_level, session_chirps

__all__ = ["ForceSource", "CsvForce", "SerialForce", "TimelineForce", "NoForce", "Recorder", "make_schedule",
           "person_timeline", "simulated_device", "location_counts",
           "recorded_locations", "record_session", "train_oneshot"]

# One-shot training's cost, measured on the shipped stationary scenario (3,097 chirps of 20,480 samples, jaco): 118 s on
# an idle 2-core machine (278 s at load 5), 199 MB of 24-bit FLAC (3.1 bytes per sample: received noise barely compresses).
ONESHOT_S_PER_SAMPLE = 118 / (3097 * 20480)
ONESHOT_BYTES_PER_SAMPLE = 199e6 / (3097 * 20480)


class ForceSource:
    """Force in N at stream time ``t_s`` (seconds since the recording started)."""

    def force(self, t_s: float) -> float:  # pragma: no cover - interface
        raise NotImplementedError


class NoForce(ForceSource):
    def force(self, t_s: float) -> float:
        return float("nan")


class CsvForce(ForceSource):
    """A force log with columns ``t_s,force_n``, interpolated at each chirp."""

    def __init__(self, path: str | Path):
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        try:
            t = np.array([float(r["t_s"]) for r in rows])
            f = np.array([float(r["force_n"]) for r in rows])
        except (KeyError, ValueError) as e:
            raise ValueError(f"{path}: a force log needs numeric columns t_s,force_n ({e})") from None
        if t.size < 2 or np.any(np.diff(t) <= 0):
            raise ValueError(f"{path}: t_s must increase and have at least two rows")
        self.t, self.f = t, f

    def force(self, t_s: float) -> float:
        return float(np.interp(t_s, self.t, self.f, left=np.nan, right=np.nan))


class SerialForce(ForceSource):
    """A serial force sensor printing one value in newtons per line (read in a thread)."""

    def __init__(self, port: str, baud: int = 115200):
        try:
            import serial  # pyserial
        except ImportError:
            raise ValueError("a serial force sensor needs pyserial: pip install pyserial") from None
        self.ser = serial.Serial(port, baud, timeout=0.5)
        self.latest = float("nan")
        self.t0 = time.perf_counter()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        while True:
            line = self.ser.readline().decode(errors="ignore").strip()
            try:
                self.latest = float(line)
            except ValueError:
                continue

    def force(self, t_s: float) -> float:
        return self.latest


class TimelineForce(ForceSource):
    """The simulated device's sensors: the person's force (plus 0.02 N of noise) and where the finger really is."""

    def __init__(self, timeline, chirp0_sample: int, fs_hz: float, n_chirp: int, seed: int = 0):
        self.tl, self.c0, self.fs, self.L = timeline, chirp0_sample, fs_hz, n_chirp
        self.rng = np.random.default_rng(seed)

    def _chirp(self, t_s: float) -> int | None:
        k = int(round((t_s * self.fs - self.c0) / self.L))
        return k if 0 <= k < len(self.tl) else None

    def force(self, t_s: float) -> float:
        k = self._chirp(t_s)
        if k is None:
            return 0.0
        f = float(self.tl.force_n[k])
        return max(0.0, f + self.rng.normal(0, 0.02)) if f > 0 else 0.0

    def contact_cm(self, t_s: float) -> tuple[float, float]:
        """Centre of the press the person is making at ``t_s`` (NaN when not pressing anywhere)."""
        k = self._chirp(t_s)
        if k is None or self.tl.location[k] < 0:
            return float("nan"), float("nan")
        return float(self.tl.x_cm[k]), float(self.tl.y_cm[k])


def make_schedule(layout: Layout, locations: list[int], rig: Rig, *, calibration_s: float = 3.0, moving_s: float = 10.0,
                  touch_s: float = 3.0, gap_s: float = 1.0, passes: int = 1) -> list[tuple[str, int, int, str]]:
    """Prompts as ``(segment, location, n_chirps, text)`` in recording order, ``passes`` times over the locations."""
    out = [("calibration", -1, rig.seconds_to_chirps(calibration_s), f"hands off the robot for {calibration_s:g} s")]
    if moving_s > 0:
        out.append(("moving", -1, rig.seconds_to_chirps(moving_s), f"start the robot moving; hands off for {moving_s:g} s"))
    for k in range(int(passes)):
        for loc in locations:
            x, y = layout.coords(np.array([loc]))[0]  # where the marker is: x around / across, y along the link
            what = f" (pass {k + 1} of {passes})" if passes > 1 else ""
            out.append(("touch", loc, rig.seconds_to_chirps(touch_s),
                        f"touch location {loc} (marker at x {x:.1f} cm, y {y:.1f} cm) with varying force for {touch_s:g} s{what}"))
            out.append(("gap", -1, rig.seconds_to_chirps(gap_s), "release"))
    return out


class Recorder:
    """Record a schedule from a source into a dataset session, one part per prompt.  Each chirp is labelled from the
    prompt whose span holds it (a skipped chirp never shifts the prompts after it), a touch prompt's after ``settle_s``."""

    def __init__(self, writer: DatasetWriter, session: str, source: AudioSource, schedule, force: ForceSource, *,
                 moving_level: float = 1.0, prompt=None, settle_s: float = 0.3, watchdog_s: float = 3.0):
        self.w, self.session, self.source, self.schedule, self.forcesrc = writer, session, source, schedule, force
        self.rig = writer.rig
        self.moving_level, self.watchdog_s = moving_level, watchdog_s
        self.prompt = prompt or (lambda text: print(f"[record] {text}", file=sys.stderr, flush=True))
        self.settle = self.rig.seconds_to_chirps(settle_s)  # reaction time at the start of a touch prompt
        self.parts_written = 0      # finished prompts on disk
        self.chirps_written = 0
        self.interrupted_at = None  # the prompt in progress when Ctrl-C came

    def _row(self, chirp: int, t_s: float, seg: str, loc: int, touching: bool) -> dict:
        row = {"chirp": chirp, "t_s": t_s, "time_s": t_s, "segment": seg,
               "location": loc if touching else -1, "x_cm": np.nan, "y_cm": np.nan,
               "force_n": self.forcesrc.force(t_s) if seg == "touch" else 0.0,
               "moving": self.moving_level if seg == "moving" else 0.0, "temperature_c": np.nan, "subject": 0}
        if touching:
            contact = getattr(self.forcesrc, "contact_cm", None)
            row["x_cm"], row["y_cm"] = contact(t_s) if contact else self.w.layout.coords(np.array([loc]))[0]
        return row

    def run(self) -> dict:
        """Record every prompt (``chirps``, ``parts``, ``complete``, ``wall_s``); on Ctrl-C finished prompts stay on disk."""
        rig, L = self.rig, self.rig.n_chirp
        framer = Framer(rig_chirp(rig))
        stream: list[np.ndarray] = []       # samples not yet written
        stream_start = 0                    # stream index of stream[0][0]
        seg_i = 0
        seg_start: int | None = None        # stream sample where the current prompt's first chirp starts
        rows: list[dict] = []
        t_wall = time.perf_counter()
        self.prompt(self.schedule[0][3])

        def close_prompt() -> None:  # write the current prompt's audio and labels as one part
            nonlocal stream, stream_start, rows, seg_i, seg_start
            end = seg_start + self.schedule[seg_i][2] * L
            audio = np.concatenate(stream)
            cut = end - stream_start
            labels = {c: np.array([r[c] for r in rows]) for c in COLUMNS}
            with _sigint_deferred():  # a finished prompt is written whole, whenever Ctrl-C comes
                self.w.write_part(self.session, self.parts_written, audio[:cut], labels)
                self.parts_written += 1
                self.chirps_written += len(rows)
            rows, stream, stream_start = [], [audio[cut:]], end
            seg_i, seg_start = seg_i + 1, end
            if seg_i < len(self.schedule):
                self.prompt(self.schedule[seg_i][3])

        try:
            for block in blocks(self.source, watchdog_s=self.watchdog_s):
                if block is None:
                    continue
                if block.discontinuity and (rows or self.parts_written):
                    raise RuntimeError("audio was lost during the recording (overflow); the prompts finished so far "
                                       "are kept: record again with --resume")
                stream.append(block.samples)
                for start, _frame in framer.push(block.samples, block.start, block.discontinuity):
                    if seg_start is None:  # the first prompt starts at the first whole chirp
                        seg_start = start
                    # Which chirp of which prompt this is, by stream position.
                    j = int(round((start - seg_start) / L))
                    while seg_i < len(self.schedule) and j >= self.schedule[seg_i][2]:
                        close_prompt()  # its last chirp(s) were not framed: the prompt still ends on time
                        j = int(round((start - seg_start) / L))
                    if seg_i >= len(self.schedule):
                        break
                    seg, loc, n, _ = self.schedule[seg_i]
                    touching = seg == "touch" and j >= self.settle
                    rows.append(self._row(self.chirps_written + len(rows), start / rig.fs_hz, seg, loc, touching))
                    if j >= n - 1:
                        close_prompt()
                        if seg_i >= len(self.schedule):
                            break
                if seg_i >= len(self.schedule):
                    break
        except KeyboardInterrupt:
            self.interrupted_at = self.schedule[seg_i] if seg_i < len(self.schedule) else None
            raise
        complete = seg_i >= len(self.schedule)
        if complete:
            self.w.finish_session(self.session, {"n_chirps": self.chirps_written, "prompts": len(self.schedule)})
        return {"chirps": self.chirps_written, "parts": self.parts_written, "complete": complete, "wall_s": time.perf_counter() - t_wall}


@contextlib.contextmanager
def _sigint_deferred():
    """Hold Ctrl-C until the block is done (cffi would swallow it inside libsndfile's callbacks); main thread only."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    old = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
    if caught and callable(old):
        old(signal.SIGINT, None)  # Python's default handler raises KeyboardInterrupt
    elif caught and old == signal.SIG_DFL:
        raise KeyboardInterrupt


def person_timeline(scenario, rig: Rig, schedule, *, seed: int, lead_chirps: int = 1):
    """What the simulated person does, chirp by chirp, given the prompts of ``schedule``: a one-session timeline.
    ``lead_chirps`` no-touch chirps go in front, so the person is never ahead of a prompt and at most one chirp behind."""
    layout = scenario.make_layout()
    rng = np.random.default_rng([seed, 17])
    subject = int(scenario.subjects[0])
    who = make_subjects()[subject]
    lengths = [n + (lead_chirps if i == 0 else 0) for i, (_, _, n, _) in enumerate(schedule)]
    n_all = sum(lengths)
    segment, event, location = np.zeros(n_all, int), np.full(n_all, -1), np.full(n_all, -1)
    x_cm, y_cm = np.full(n_all, np.nan), np.full(n_all, np.nan)
    force_n, moving = np.zeros(n_all), np.zeros(n_all)
    a = 0
    for i, ((seg, loc, _, _), n) in enumerate(zip(schedule, lengths)):
        b = a + n
        segment[a:b] = SEGMENTS.index(seg)
        if seg == "touch":
            peak = rng.uniform(*scenario.peak_force_n) * who.max_force_n / 6.0
            force_n[a:b] = press_profile(n, peak_n=peak, rng=rng)
            aim_cm = (np.array(who.aim_bias_m) + rng.normal(0, who.aim_jitter_m, 2)) * 100
            x_cm[a:b], y_cm[a:b] = layout.coords(np.array([loc]))[0] + aim_cm
            event[a:b], location[a:b] = i, loc
        elif seg == "moving":
            moving[a:b] = _motion_level(rng, n, rig.chirps_per_s) * float(scenario.motion.get("level", 1.0))
        a = b
    k = np.arange(n_all)
    time_s = scenario.start_s + k / rig.chirps_per_s
    return Timeline(session=np.zeros(n_all, int), chirp=k, time_s=time_s, segment=segment, event=event, location=location,
                    x_cm=x_cm, y_cm=y_cm, force_n=force_n, moving=moving, temperature_c=scenario.temperature_c(time_s),
                    subject=np.full(n_all, subject))


def simulated_device(scenario, rig: Rig, schedule, *, session_index: int, realtime: bool = False, offset: int = 4321):
    """The simulated rig with a simulated person who follows ``schedule``: ``(source, force, timeline)``."""
    moving = any(seg == "moving" for seg, *_ in schedule)
    psc = scenario.replace(sessions=1, seed=scenario.seed + 500 + session_index, motion={**scenario.motion, "enabled": moving})
    offset %= rig.n_chirp
    tl = person_timeline(psc, rig, schedule, seed=psc.seed, lead_chirps=1 if offset else 0)
    src = open_source(rig, SIM, [Link()], play=lambda _: (Simulator(psc, rig), tl), realtime=realtime, offset=offset)
    return src, TimelineForce(tl, -offset, rig.fs_hz, rig.n_chirp, seed=session_index), tl


def next_session(root: Path) -> str:
    existing = sorted(p.name for p in root.iterdir() if p.is_dir() and p.name.startswith("s")) if root.exists() else []
    nums = [int(n[1:]) for n in existing if n[1:].isdigit()]
    return f"s{(max(nums) + 1 if nums else 0):03d}"


MIN_TOUCH_CHIRPS = 3  # a location with fewer touch chirps than this is recorded again by --resume


def location_counts(root: str | Path, *, min_force_n: float = 0.5) -> dict[int, tuple[int, int, int]]:
    """Per location, in the finished parts of a dataset: ``(labelled chirps, touch chirps, presses)`` as ``fit-svm``
    counts them; a press is a run of chirps there within a session with at least :data:`MIN_TOUCH_CHIRPS` touch chirps."""
    ds = Dataset(root)
    out: dict[int, tuple[int, int, int]] = {}
    for s in ds.sessions:
        labs = [ds._read_labels(ds.root / s / f"part-{p:05d}.csv") for p in ds.parts(s)]
        if not labs:
            continue
        loc, f = np.concatenate([lb["location"] for lb in labs]), np.concatenate([lb["force_n"] for lb in labs])
        press, use = press_ids(loc, np.zeros(loc.size, int)), (f >= min_force_n) | np.isnan(f)
        for v in np.unique(loc[loc >= 0]):
            at = loc == v
            k = sum(int(np.sum((press == p) & use) >= MIN_TOUCH_CHIRPS) for p in np.unique(press[at]))
            n, t, c = out.get(int(v), (0, 0, 0))
            out[int(v)] = (n + int(at.sum()), t + int(np.sum(at & use)), c + k)
    return out


def recorded_locations(root: str | Path, *, min_force_n: float = 0.5, min_chirps: int = MIN_TOUCH_CHIRPS) -> set[int]:
    """Locations with at least ``min_chirps`` touch chirps in the finished parts of a dataset."""
    return {v for v, (_, t, _) in location_counts(root, min_force_n=min_force_n).items() if t >= min_chirps}


def check_record_size(rig: Rig, n_locations: int, *, calibration_s: float, moving_s: float, touch_s: float,
                      gap_s: float) -> None:
    """Refuse prompt lengths whose audio or simulated timeline would not fit in memory, before anything is opened."""
    for name, v in (("calibration-s", calibration_s), ("moving-s", moving_s), ("touch-s", touch_s), ("gap-s", gap_s)):
        if not np.isfinite(v):
            raise ValueError(f"--{name} must be a finite number of seconds, got {v!r}")
    longest = max(calibration_s, moving_s, touch_s, gap_s)
    n_prompt = rig.seconds_to_chirps(longest)
    check_memory(3.0 * 4 * rig.n_chirp * n_prompt, f"a prompt of {longest:g} s ({n_prompt:.3g} chirps of audio held until it ends)",
                 "record shorter prompts (--calibration-s, --moving-s, --touch-s, --gap-s)")
    total = (rig.seconds_to_chirps(calibration_s) + rig.seconds_to_chirps(moving_s)
             + n_locations * (rig.seconds_to_chirps(touch_s) + rig.seconds_to_chirps(gap_s)))
    check_memory(256.0 * total, f"the session's labels ({total:.3g} chirps)", "record fewer or shorter prompts")


def record_session(out: str | Path, rig: Rig, scenario, *, locations=None, device=SIM, resume: bool = False,
                   overwrite: bool = False, realtime: bool = True, calibration_s: float = 3.0, moving_s: float = 10.0,
                   touch_s: float = 3.0, gap_s: float = 1.0, force_csv=None, force_serial=None, tx: int = 0, rx: int = 0,
                   min_force_n: float = 0.5, passes: int = 1, artifact: str | Path | None = None, prompt=None, log=None,
                   report=None, link=None) -> dict:
    """``sonicskin record``: one guided session into the dataset ``out``; with ``artifact``, the SVM artifact trained on
    everything recorded so far once every marker is pressed.  Returns :meth:`Recorder.run`'s figures plus ``session``
    and ``locations`` (``{"locations": []}`` when nothing is missing)."""
    log = log or (lambda text: print(text, file=sys.stderr, flush=True))
    out = Path(out)
    layout = scenario.make_layout()
    wanted = list(dict.fromkeys(int(v) for v in locations)) if locations else list(layout.ids)
    bad = [v for v in wanted if v not in layout.ids]
    if bad:
        raise ValueError(f"--locations {' '.join(map(str, bad))}: not a marker of the {scenario.name} layout "
                         f"(ids {layout.ids[0]}..{layout.ids[-1]})")
    if not is_number(passes, integer=True) or passes < 1:
        raise ValueError(f"--passes must be a whole number >= 1, got {passes!r}")
    for name, v in (("calibration-s", calibration_s), ("touch-s", touch_s)):
        if not v > 0:
            raise ValueError(f"--{name} must be > 0 s, got {v:g}")
    for name, v in (("moving-s", moving_s), ("gap-s", gap_s)):
        if not v >= 0:
            raise ValueError(f"--{name} must be >= 0 s, got {v:g}")
    if simulated(device) and (force_csv or force_serial):  # was silently ignored (a missing file too)
        opt = f"--force-csv {force_csv}" if force_csv else f"--force-serial {force_serial}"
        raise ValueError(f"{opt}: the simulated device (--device sim) measures its own force and reads no force sensor; "
                         f"drop {opt.split()[0]}, or record from an audio interface (--device NAME|INDEX)")
    check_record_size(rig, len(wanted), calibration_s=calibration_s, moving_s=moving_s, touch_s=touch_s, gap_s=gap_s)
    if calibration_s < 3.0:
        log(f"warning: --calibration-s {calibration_s:g} is shorter than Alg. 2's 3 s of hands-off chirps: "
            f"fit-svm will need --mode absolute on this recording")
    if not simulated(device):  # the device and the force sensor open before anything is written
        src = open_source(rig, device, [Link(tx=tx, rx=rx)])
        force = CsvForce(force_csv) if force_csv else SerialForce(force_serial) if force_serial else NoForce()
    mode = "resume" if resume else ("overwrite" if overwrite else "create")
    new_dir, new_dataset = not out.exists(), not (out / "dataset.json").exists()
    source = {"kind": "recorder", "layout_from": scenario.name}
    if simulated(device):  # the wall the simulated device plays: a link's artifact trained on it runs on that link
        source["scenario"] = scenario.to_dict()
    writer = DatasetWriter(out, rig, layout, source=source, mode=mode)
    new_dataset = new_dataset or overwrite
    todo = wanted
    if resume:  # what is missing of --passes presses per location (a press: >= MIN_TOUCH_CHIRPS touch chirps)
        counts = location_counts(out, min_force_n=min_force_n)
        short = {v: passes - counts.get(v, (0, 0, 0))[2] for v in wanted if counts.get(v, (0, 0, 0))[2] < passes}

        def why(v: int) -> str:
            n, t, k = counts.get(v, (0, 0, 0))
            return (f"{k} of {passes} presses" if k else
                    f"labelled but only {t} of {n} chirps pressed at >= {min_force_n:g} N" if n else "not recorded")

        if short:
            log(f"{out}: resuming: recording {sum(short.values())} missing press(es) at {len(short)} location(s): "
                + ", ".join(f"{v} ({why(v)})" for v in short))
            todo, passes = [v for k in range(max(short.values())) for v in wanted if short.get(v, 0) > k], 1  # pass by pass
        else:
            log(f"{out}: all {len(wanted)} requested locations have {passes} press{'es' if passes > 1 else ''}; nothing "
                f"to record")
            if artifact is None or (Path(artifact) / "skin.json").is_file():
                return {"locations": []}
            todo = []  # the run that recorded them was stopped before it wrote its artifact: write it now
    report = report or (lambda text: print(text, flush=True))
    res, session = {"chirps": 0, "parts": 0}, None
    if todo:
        session = next_session(out)
        schedule = make_schedule(layout, todo, rig, calibration_s=calibration_s, moving_s=moving_s, touch_s=touch_s, gap_s=gap_s,
                                 passes=passes)
        if simulated(device):
            src, force, _ = simulated_device(scenario, rig, schedule, session_index=int(session[1:]), realtime=realtime)
        log(f"recording session {session} of {out}: locations {' '.join(map(str, todo))}, "
            f"{sum(n for _, _, n, _ in schedule) * rig.period_s:.0f} s")
        rec = Recorder(writer, session, src, schedule, force, prompt=prompt)
        try:
            with src:
                res = rec.run()
        except BaseException as exc:
            if rec.parts_written == 0 and new_dataset:  # nothing recorded: leave no dataset that blocks a retry
                if new_dir:
                    shutil.rmtree(out, ignore_errors=True)
                else:
                    shutil.rmtree(out / session, ignore_errors=True)
                    (out / "dataset.json").unlink(missing_ok=True)
                kept = f"nothing was recorded, so the new dataset {out} is removed"
            else:
                kept = (f"{rec.parts_written} finished prompts ({rec.chirps_written} chirps) are kept in {out / session}; "
                        f"`--resume` records what is missing")
            if isinstance(exc, KeyboardInterrupt):
                log(f"interrupted{f' during {rec.interrupted_at[3]!r}' if rec.interrupted_at else ''}: {kept}")
            raise
        report(f"wrote {res['chirps']} chirps in {res['parts']} parts to {out / session}")
    if artifact is not None:
        counts = location_counts(out, min_force_n=min_force_n)
        missing = sorted(v for v in layout.ids if counts.get(int(v), (0, 0, 0))[1] < MIN_TOUCH_CHIRPS)
        if missing:  # a press shorter than the force ramp is never firm enough: --resume alone would repeat it for ever
            brief_ = len(set(missing) & set(todo))
            hint = (f"; {brief_} of them were prompted in this run but gave fewer than {MIN_TOUCH_CHIRPS} chirps at >= "
                    f"{min_force_n:g} N: press longer (--touch-s, now {touch_s:g} s)" if brief_ else "")
            report(f"no artifact yet: location(s) {', '.join(map(str, missing[:12]))}{', ...' if len(missing) > 12 else ''} "
                   f"of the layout have no press yet{hint}; `--resume` records them, then the artifact is written")
        else:  # the skin trained on everything recorded so far, with what validation expects of it
            build_svm_artifact(out, artifact, min_force_n=min_force_n, progress=False, log=report,
                               training={"link": {"name": link.name, "frame": link.frame}} if link else None)
            report(f"deploy it: sonicskin live --artifact {artifact}" + ("" if simulated(device) else f" --device {device}"))
    return {**res, "session": session, "locations": todo}


def train_oneshot(scenario, rig: Rig, root: Path = Path("."), log=None) -> Path:
    """One-shot training on the simulated link (cached under ``root``) for a run without an artifact."""
    log = log or (lambda m: print(m, file=sys.stderr))
    art = root / f"artifacts/sim-{scenario.name}-svm"
    if (art / "skin.json").is_file():
        log(f"no --artifact: using {art}, trained on the simulated {scenario.name!r} link by an earlier run (delete it to "
            f"train again)")
        return art
    data = root / f"data/sim-{scenario.name}-oneshot"
    samples = session_chirps(scenario, rig)[0] * rig.n_chirp
    est_s = samples * ONESHOT_S_PER_SAMPLE
    took = f"about {est_s / 60:.0f} min" if est_s >= 90 else f"about {max(est_s, 1):.0f} s"
    log(f"no --artifact: training an SVM on the simulated {scenario.name!r} link first, once: {took} on an idle 2-core "
        f"machine (longer when it is busy), {samples * ONESHOT_BYTES_PER_SAMPLE / 1e6:,.0f} MB of simulated recordings "
        f"written to {data}, the artifact to {art} (reused by later runs); pass --artifact DIR to run a trained one")
    generate.simulate_dataset(scenario.replace(sessions=1), rig, data, mode="overwrite", progress=False, log=log)
    build_svm_artifact(data, art, progress=False, log=log)
    return art
