"""Write a scenario's simulated recordings in the dataset format (``sonicskin simulate``)."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..dataset import DatasetWriter
from ..rig import Rig
from .scenario import SEGMENTS, Scenario, build_timeline
from .simulator import Simulator

__all__ = ["simulate_dataset"]


def simulate_dataset(scenario: Scenario, rig: Rig, out: str | Path, *, mode: str = "create",
                     progress: bool = True, log=print) -> dict:
    """Render every session of ``scenario`` into the dataset ``out``, one stream each; returns timing figures."""
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    sim = Simulator(scenario, rig)
    setup_s = time.perf_counter() - t0
    tl = build_timeline(scenario, rig)
    writer = DatasetWriter(out, rig, sim.layout, source={"kind": "simulator", "scenario": scenario.to_dict()}, mode=mode)
    L = rig.n_chirp
    per_part = max(1, rig.seconds_to_chirps(scenario.part_s))
    sensor_rng = np.random.default_rng([scenario.seed, 11])
    n_done = 0
    render_s = 0.0
    todo = [s for s in range(scenario.sessions) if not writer.session_done(f"s{s:03d}")]
    bar = tqdm(total=int(np.isin(tl.session, todo).sum()), unit="chirp", desc=f"simulate {scenario.name}",
               disable=None if progress else True)
    pending: list = []
    # Two frame buffers in turn: block b renders into one while the parts of block b - 1 are still
    # being encoded from the other (reused memory: no fresh pages per block).
    # The frames are rendered as 24-bit PCM codes (int32, see Simulator.render): the FLAC holds the same samples
    # as from float frames, without libsndfile's float conversion.
    bufs: list = [np.empty((0, L), np.int32)] * 2
    buf_jobs: list[list] = [[], []]
    n_block = 0
    with ThreadPoolExecutor(max_workers=1) as io_pool:
        for s in todo:
            name = f"s{s:03d}"
            st = tl.select(tl.session == s)
            rng = np.random.default_rng([scenario.seed, 5, s])
            offset = int(rng.integers(1, L))  # the recording starts mid-chirp
            # The force sensor (SingleTact-like): ground truth plus 0.02 N noise, never negative.
            f_meas = np.clip(st.force_n + np.where(st.force_n > 0, sensor_rng.normal(0, 0.02, len(st)), 0), 0, None)
            # Render in blocks of whole parts (>= ~1000 chirps: the contact Green's functions of all
            # presses in a block are one matrix product), then write part by part.
            block = per_part * max(1, 1024 // per_part)
            for b in range(0, len(st), block):
                bidx = np.arange(b, min(b + block, len(st)))
                j = n_block % 2
                n_block += 1
                for f in buf_jobs[j]:
                    f.result()  # the encoder is done with this buffer
                buf_jobs[j] = []
                if bufs[j].shape[0] < bidx.size:
                    bufs[j] = np.empty((block, L), np.int32)
                tr = time.perf_counter()
                frames_b = sim.render(st.select(bidx), out=bufs[j][:bidx.size])
                render_s += time.perf_counter() - tr
                for a in range(b, bidx[-1] + 1, per_part):
                    p = a // per_part
                    idx = np.arange(a, min(a + per_part, len(st)))
                    frames = frames_b[a - b:a - b + idx.size]  # a view: the encoder reads the render buffer itself
                    if p == 0:
                        lead = frames[0, L - offset:]  # tail of the chirp before the first whole one
                        audio = np.concatenate([lead, frames.ravel()])
                    else:
                        audio = frames.ravel()
                    if idx[-1] == len(st) - 1:  # the recording stops somewhere in the next chirp
                        audio = np.concatenate([audio, frames[-1, : L // 2]])
                    t_s = (offset + idx * L) / rig.fs_hz
                    labels = {
                        "chirp": idx, "t_s": t_s, "time_s": st.time_s[idx],
                        "segment": np.array([SEGMENTS[k] for k in st.segment[idx]]), "location": st.location[idx],
                        "x_cm": st.x_cm[idx], "y_cm": st.y_cm[idx], "force_n": f_meas[idx], "moving": st.moving[idx],
                        "temperature_c": st.temperature_c[idx], "subject": st.subject[idx],
                    }
                    # FLAC encoding overlaps the next block's rendering (libsndfile releases the GIL).
                    pending.append(io_pool.submit(writer.write_part, name, p, audio, labels))
                    buf_jobs[j].append(pending[-1])
                    n_done += idx.size
                    bar.update(idx.size)
            for f in pending:
                f.result()  # re-raise write errors; every part is on disk before the session is marked done
            pending.clear()
            writer.finish_session(name, {"n_chirps": len(st), "offset_samples": offset})
    bar.close()
    total_s = time.perf_counter() - t0
    fig = {"setup_s": setup_s, "chirps": n_done, "render_s": render_s, "total_s": total_s,
           "render_chirps_per_s": n_done / render_s if render_s else float("nan"),
           "total_chirps_per_s": n_done / total_s if total_s else float("nan")}
    log(f"simulated {n_done} chirps ({n_done * rig.period_s / 60:.1f} min of audio) in {total_s:.1f} s: "
        f"setup {setup_s:.1f} s, rendering {fig['render_chirps_per_s']:.0f} chirps/s, "
        f"with FLAC writing {fig['total_chirps_per_s']:.0f} chirps/s")
    return fig
