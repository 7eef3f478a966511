"""Run the README's command blocks and write what they print into it (``make docs``); check them (tests/test_readme.py).

The README marks its shell blocks with HTML comments, which GitHub does not render:

``<!-- run: NAME [exact] [timeout=SECONDS] [mask=REGEX ...] -->``
    before a fenced ``bash`` block: the block is run, in README order, as one ``bash -e`` script in a
    fresh folder (see below). ``exact``: its printed output is deterministic, and the test fails when it
    differs from the README's output block (after masking timings, see ``MASKS``; ``mask=REGEX`` adds a
    pattern whose matches are masked too). ``timeout``: seconds (default 1800).
``<!-- norun: REASON -->``
    before a fenced ``bash`` block that is not run (it needs hardware, or it is the test suite itself).
    Every ``bash`` block needs one of these two markers, so a new section cannot slip through unchecked.
``<!-- small: NAME`` ... ``-->``
    a multi-line comment whose body is the block's small variant: a script run instead of the block by the
    test, with the same effect on the folder (the same files for the blocks after it) on a smaller scale.
    ``make docs`` runs a block as written when the README shows what it printed (an output block, or a
    figure ``after`` it), else its small variant (the real one may take hours: ``--full`` runs them all
    as written). A block without a small variant always runs as written.
``<!-- output: NAME -->``
    where the output of run block NAME goes: the generator writes (or replaces) the fenced ``text`` block
    after the marker, each command's output under a ``$ command`` line, the temporary folder's path
    replaced by ``.``. Unless NAME is ``exact``, one line ``<sub>Printed by `make docs` on ...</sub>``
    follows the block, saying on what machine, at which load and when it ran, and how long it took.
``<!-- figure: docs/FILE.png from=PATH [after=NAME] [width=PIXELS] -->``
    before the image line ``![...](docs/FILE.png)``: the generator copies PATH (relative to the run folder)
    to docs/FILE.png after block NAME ran (default: after the last block), scaled down to at most
    ``width`` pixels wide (default 900) to keep the committed PNGs small.

The run folder is a fresh temporary folder holding copies of what the commands need from the
repository (``COPY``: examples/, configs/, benchmarks/, the Makefile and the files it depends on; extend
it when a new block needs more), and ``.venv``, links to the entries of the project's virtual environment
(the one running this script) plus a fresh install marker, so ``make`` never re-installs into it; its
``bin`` is first on PATH, so ``sonicskin``, ``python`` and ``make demo`` run the installed code as a
user's shell would.
Output is stdout and stderr interleaved as a terminal shows them (``PYTHONUNBUFFERED``), with what a
carriage return overwrote and progress bars left out (``TQDM_DISABLE=1``, and any bar that still gets
through is dropped), trailing blanks stripped.

A failing command stops the run with the block's name, README line and last output lines; ``make docs``
still writes the outputs of the blocks before it. It re-reads README.md before writing, so edits made
while it ran are kept.

    python tools/readme.py            # make docs: run the blocks, rewrite README.md and docs/*.png
    python tools/readme.py --full     # the same, every block as written (hours: the seed sweeps)
    python tools/readme.py --check    # what the test does: small variants, compare exact outputs
    python tools/readme.py --list     # the marked blocks and their variants
    python tools/readme.py --only spectra wav   # re-run blocks that need nothing before them
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import difflib
import os
import platform
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
COPY = ("examples", "configs", "benchmarks", "Makefile", "pyproject.toml", "constraints.txt")
DEFAULT_TIMEOUT_S = 1800.0
# Volatile numbers masked before an exact comparison: durations and rates.
MASKS = (
    r"\d+(?:\.\d+)?(?=\s*(?:s|ms|us|µs|min|h)\b)",
    r"\d+(?:\.\d+)?(?=\s*[A-Za-z]+/s\b)",
)

_MARK = re.compile(r"^<!--\s*(run|norun|small|output|figure):\s*(.*?)\s*(-->)?\s*$")
_FENCE = re.compile(r"^(```+|~~~+)\s*([\w+-]*)")
STAMP_PREFIX = "<sub>Printed by `make docs`"


class ReadmeError(Exception):
    """The README's markers are malformed, or a block failed or printed something else."""


@dataclasses.dataclass
class Block:
    name: str
    script: str  # the commands as the README shows them
    line: int  # 1-based line of the marker
    exact: bool = False
    timeout_s: float = DEFAULT_TIMEOUT_S
    masks: tuple[str, ...] = ()
    small: str | None = None

    def variant(self, small: bool) -> str:
        return self.small if small and self.small is not None else self.script


@dataclasses.dataclass
class Output:
    name: str
    start: int  # 0-based index of the marker line
    end: int  # index after the region (marker, fenced block, stamp line)
    text: str | None  # the fenced block's content, None when there is none yet


@dataclasses.dataclass
class Figure:
    dest: str
    src: str
    after: str | None
    width: int
    line: int


@dataclasses.dataclass
class Readme:
    lines: list[str]
    blocks: list[Block]
    outputs: list[Output]
    figures: list[Figure]
    norun: list[tuple[int, str]]


def _attrs(text: str, line: int) -> tuple[str, dict[str, list[str]], set[str]]:
    try:
        words = shlex.split(text)
    except ValueError as e:
        raise ReadmeError(f"README.md:{line}: cannot parse {text!r}: {e}") from None
    if not words:
        raise ReadmeError(f"README.md:{line}: a marker needs a name")
    kv: dict[str, list[str]] = {}
    flags: set[str] = set()
    for w in words[1:]:
        if "=" in w:
            k, v = w.split("=", 1)
            kv.setdefault(k, []).append(v)
        else:
            flags.add(w)
    return words[0], kv, flags


def _fence_at(lines: list[str], i: int) -> tuple[int, int, str] | None:
    """(first content line, index after the closing fence, info string) of a fenced block at or after line i (blanks skipped)."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        return None
    m = _FENCE.match(lines[i])
    if not m:
        return None
    j = i + 1
    while j < len(lines) and not lines[j].startswith(m.group(1)):
        j += 1
    if j >= len(lines):
        raise ReadmeError(f"README.md:{i + 1}: unclosed code block")
    return i + 1, j + 1, m.group(2)


def parse(text: str) -> Readme:
    lines = text.split("\n")
    blocks: dict[str, Block] = {}
    order: list[Block] = []
    outputs: list[Output] = []
    figures: list[Figure] = []
    smalls: dict[str, tuple[int, str]] = {}
    norun: list[tuple[int, str]] = []
    covered: set[int] = set()  # first lines of bash blocks that carry a marker
    i = 0
    while i < len(lines):
        ln = lines[i]
        fence = _FENCE.match(ln)
        if fence:  # skip code blocks: markers inside them are text
            info = fence.group(2)
            j = i + 1
            while j < len(lines) and not lines[j].startswith(fence.group(1)):
                j += 1
            if info in ("bash", "sh", "shell", "console") and i not in covered:
                raise ReadmeError(f"README.md:{i + 1}: a {info} block without `<!-- run: NAME -->` or `<!-- norun: REASON -->` "
                                  f"before it (tools/readme.py says how to mark it)")
            i = j + 1
            continue
        m = _MARK.match(ln)
        if not m:
            i += 1
            continue
        kind, rest, closed = m.group(1), m.group(2), m.group(3)
        if kind == "small":
            if closed:
                raise ReadmeError(f"README.md:{i + 1}: `<!-- small: NAME` takes the script on the lines below it, "
                                  f"closed by a line `-->`")
            j = i + 1
            while j < len(lines) and lines[j].strip() != "-->":
                j += 1
            if j >= len(lines):
                raise ReadmeError(f"README.md:{i + 1}: `<!-- small: {rest}` is not closed by a line `-->`")
            name = rest.split()[0] if rest.split() else ""
            if name in smalls:
                raise ReadmeError(f"README.md:{i + 1}: a second small variant of {name!r}")
            smalls[name] = (i + 1, "\n".join(lines[i + 1:j]).strip() + "\n")
            i = j + 1
            continue
        if not closed:
            raise ReadmeError(f"README.md:{i + 1}: a `<!-- {kind}: ... -->` marker must be one line")
        if kind in ("run", "norun"):
            f = _fence_at(lines, i + 1)
            if f is None or f[2] not in ("bash", "sh", "shell"):
                raise ReadmeError(f"README.md:{i + 1}: `<!-- {kind}: ... -->` must stand right before a ```bash block")
            covered.add(f[0] - 1)
            if kind == "norun":
                if not rest:
                    raise ReadmeError(f"README.md:{i + 1}: `<!-- norun: REASON -->` needs a reason")
                norun.append((i + 1, rest))
            else:
                name, kv, flags = _attrs(rest, i + 1)
                unknown = (flags - {"exact"}) | (set(kv) - {"timeout", "mask"})
                if unknown:
                    raise ReadmeError(f"README.md:{i + 1}: unknown run attribute(s) {sorted(unknown)}; "
                                      f"known: exact, timeout=SECONDS, mask=REGEX")
                if name in blocks:
                    raise ReadmeError(f"README.md:{i + 1}: a second run block named {name!r}")
                for rx in kv.get("mask", []):
                    re.compile(rx)
                b = Block(name, "\n".join(lines[f[0]:f[1] - 1]) + "\n", i + 1, exact="exact" in flags,
                          timeout_s=float(kv.get("timeout", [DEFAULT_TIMEOUT_S])[0]),
                          masks=tuple(kv.get("mask", [])))
                blocks[name] = b
                order.append(b)
            i += 1
            continue
        if kind == "output":
            name, _, _ = _attrs(rest, i + 1)
            f = _fence_at(lines, i + 1)
            if f is not None and f[2] in ("", "text"):
                end, content = f[1], "\n".join(lines[f[0]:f[1] - 1])
                if end < len(lines) and lines[end].startswith(STAMP_PREFIX):
                    end += 1
            else:
                end, content = i + 1, None
            outputs.append(Output(name, i, end, content))
            i = end
            continue
        if kind == "figure":
            dest, kv, _ = _attrs(rest, i + 1)
            if not dest.startswith("docs/") or not dest.endswith(".png") or "from" not in kv:
                raise ReadmeError(f"README.md:{i + 1}: `<!-- figure: docs/NAME.png from=PATH -->` (a PNG under docs/)")
            figures.append(Figure(dest, kv["from"][0], kv.get("after", [None])[0], int(kv.get("width", ["900"])[0]), i + 1))
        i += 1
    for name, (line, _) in smalls.items():
        if name not in blocks:
            raise ReadmeError(f"README.md:{line}: small variant of {name!r}, but no `<!-- run: {name} -->` block")
        blocks[name].small = smalls[name][1]
    names = [b.name for b in order]
    for o in outputs:
        if o.name not in blocks:
            raise ReadmeError(f"README.md:{o.start + 1}: output of {o.name!r}, but no `<!-- run: {o.name} -->` block")
    for fig in figures:
        if fig.after is not None and fig.after not in blocks:
            raise ReadmeError(f"README.md:{fig.line}: figure after {fig.after!r}, but no such run block ({names})")
    return Readme(lines, order, outputs, figures, norun)


def shown(readme: Readme) -> set[str]:
    """Names of the blocks whose printed output or files the README shows."""
    return {o.name for o in readme.outputs} | {f.after for f in readme.figures if f.after} | (
        {readme.blocks[-1].name} if readme.blocks and any(f.after is None for f in readme.figures) else set())


def commands(script: str) -> list[str]:
    """The script's commands, one per logical line (backslash continuations joined), comments and blanks left out."""
    out, cur = [], ""
    for ln in script.splitlines():
        if not cur and (not ln.strip() or ln.lstrip().startswith("#")):
            continue
        cur += ln + "\n"
        if not ln.rstrip().endswith("\\"):
            out.append(cur.rstrip("\n"))
            cur = ""
    if cur:
        out.append(cur.rstrip("\n"))
    return out


def _shown(cmd: str) -> str:
    """The command as the output block shows it: without trailing ``# comments`` (outside quotes)."""
    out = []
    for ln in cmd.split("\n"):
        for m in re.finditer(r"\s#", ln):
            before = ln[:m.start()]
            if before.count('"') % 2 == 0 and before.count("'") % 2 == 0:
                ln = before + (" \\" if ln.rstrip().endswith("\\") else "")
                break
        out.append(ln.rstrip())
    return "\n".join(out)


def to_script(script: str) -> str:
    """A bash script that prints ``$ command`` before running each command and stops at the first failure."""
    parts = ["set -eo pipefail"]
    for cmd in commands(script):
        parts.append(f"printf '%s\\n' {shlex.quote('$ ' + _shown(cmd))}")
        parts.append(cmd)
    return "\n".join(parts) + "\n"


_BAR = re.compile(r"^[^|]*\d+%\|[^|]*\|.*\]\s*$")


def clean(text: str) -> str:
    """What a terminal would leave of ``text`` (the last of carriage-return-overwritten segments), without progress
    bars (a piped run should print none: the commands turn them off when stderr is not a terminal) and trailing blanks."""
    lines = []
    for ln in text.split("\n"):
        segs = [seg for seg in ln.split("\r") if seg.strip()]
        if "\r" in ln and (not segs or _BAR.match(segs[-1])):
            continue
        ln = segs[-1] if segs else ""
        if not _BAR.match(ln):
            lines.append(ln.rstrip())
    return "\n".join(lines)


def mask(text: str, extra: tuple[str, ...] = ()) -> str:
    for rx in (*MASKS, *extra):
        text = re.sub(rx, "#", text)
    return "\n".join(ln.rstrip() for ln in text.strip("\n").split("\n"))


def _venv_bin() -> Path:
    return Path(sys.executable).parent


def prepare(folder: Path) -> None:
    """Copy what the commands need into ``folder``; ``.venv`` links to the running virtual environment."""
    for name in COPY:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, folder / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"), dirs_exist_ok=True)
        elif src.is_file():
            shutil.copy2(src, folder / name)  # keeps mtimes: make must not see pyproject.toml as newer than the install
    venv, link = _venv_bin().parent, folder / ".venv"
    if not link.exists():  # the venv's entries linked, and a fresh install marker: `make demo` never installs there
        link.mkdir()
        for entry in venv.iterdir():
            if entry.name != ".installed":
                (link / entry.name).symlink_to(entry, target_is_directory=entry.is_dir())
        (link / ".installed").touch()


def environment(folder: Path) -> dict[str, str]:
    env = dict(os.environ)
    bin_ = str(_venv_bin())
    for k in ("MAKELEVEL", "MAKEFLAGS", "MFLAGS"):  # under `make docs`: the blocks' make is a top-level make
        env.pop(k, None)
    env.update(PATH=bin_ + os.pathsep + env.get("PATH", ""), VIRTUAL_ENV=str(_venv_bin().parent),
               PYTHONUNBUFFERED="1", PYTHONDONTWRITEBYTECODE="1", TERM="dumb", COLUMNS="120", LC_ALL="C.UTF-8",
               # `make demo` must use the linked venv as installed, never re-install into it from the copy
               MAKEFLAGS="-o .venv/.installed", TQDM_DISABLE="1")
    for k in ("PYTEST_CURRENT_TEST", "PYTEST_XDIST_WORKER", "PYTHONPATH"):
        env.pop(k, None)
    return env


@dataclasses.dataclass
class Ran:
    block: Block
    small: bool
    output: str
    seconds: float
    load: float


def run_block(block: Block, folder: Path, small: bool, echo=None) -> Ran:
    """Run one block in ``folder``; its combined stdout/stderr (folder path as ``.``). Raises ReadmeError on failure."""
    script = to_script(block.variant(small))
    load = os.getloadavg()[0]
    t0 = time.monotonic()
    proc = subprocess.Popen(["bash", "-c", script], cwd=folder, env=environment(folder), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, start_new_session=True)  # bytes: keep carriage returns
    timer = threading.Timer(block.timeout_s, lambda: os.killpg(proc.pid, 9))
    timer.start()
    chunks = []
    try:
        for raw in proc.stdout:
            ln = raw.decode("utf-8", errors="replace")
            chunks.append(ln)
            if echo:
                echo(ln)
        code = proc.wait()
    finally:
        timer.cancel()
        if proc.poll() is None:  # interrupted: take the block's processes along
            os.killpg(proc.pid, 9)
            proc.wait()
    seconds = time.monotonic() - t0
    out = "".join(chunks)
    for p in sorted({str(folder), os.path.realpath(folder)}, key=len, reverse=True):
        out = out.replace(p + "/", "").replace(p, ".")
    out = clean(out)
    if code != 0:
        why = f"timed out after {block.timeout_s:g} s" if seconds >= block.timeout_s else f"exit code {code}"
        tail = "\n".join(out.rstrip().split("\n")[-25:])
        raise ReadmeError(f"README.md:{block.line}: block {block.name!r} ({'small variant' if small and block.small else 'as written'}) "
                          f"failed: {why}; its last lines:\n{tail}")
    return Ran(block, small, out.rstrip() + "\n", seconds, load)


def copy_figure(fig: Figure, folder: Path, root: Path = ROOT) -> Path:
    src = folder / fig.src
    if not src.is_file():
        raise ReadmeError(f"README.md:{fig.line}: figure {fig.dest}: {fig.src} was not written by the blocks")
    from PIL import Image

    dest = root / fig.dest
    dest.parent.mkdir(parents=True, exist_ok=True)
    with Image.open(src) as im:
        if im.width > fig.width:
            im = im.resize((fig.width, round(im.height * fig.width / im.width)), Image.LANCZOS)
        im.save(dest, optimize=True)
    return dest


def compare_exact(ran: Ran, readme: Readme) -> None:
    """Fail when an exact block printed something other than its README output block (volatile numbers masked)."""
    for o in readme.outputs:
        if o.name != ran.block.name:
            continue
        want, got = mask(o.text or "", ran.block.masks), mask(ran.output, ran.block.masks)
        if want != got:
            diff = "\n".join(difflib.unified_diff(want.split("\n"), got.split("\n"), "README.md", "this commit", lineterm="", n=1))
            raise ReadmeError(f"README.md:{o.start + 1}: the output of {ran.block.name!r} is stale; run `make docs`:\n{diff}")


def run_all(small: bool, check: bool, readme: Readme | None = None, echo=None, figures: bool = False,
            keep: Path | None = None, full: bool = False, only: list[str] | None = None) -> list[Ran]:
    """Run every block in order in a fresh folder. ``small``: every small variant (the test); else the small variants
    of the blocks whose output the README does not show (``full``: none). ``check``: compare the exact outputs."""
    readme = readme or parse(README.read_text())
    as_written = set() if small else {b.name for b in readme.blocks} if full else shown(readme)
    results = []
    with tempfile.TemporaryDirectory(prefix="sonicskin-readme-") as tmp:
        folder = keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        prepare(folder)
        for b in readme.blocks:
            if only and b.name not in only:
                continue
            use_small = b.name not in as_written
            if echo:
                echo(f"\n=== {b.name} ({'small variant' if use_small and b.small else 'as written'}, README.md:{b.line})\n")
            try:
                ran = run_block(b, folder, use_small, echo)
                if check and b.exact:
                    compare_exact(ran, readme)
            except ReadmeError as e:
                e.results = results  # what ran before: make docs still writes their outputs
                raise
            results.append(ran)
            if figures:
                for fig in readme.figures:
                    if fig.after == b.name:
                        copy_figure(fig, folder)
        if figures:
            for fig in readme.figures:
                if fig.after is None:
                    copy_figure(fig, folder)
    return results


def _machine() -> str:
    try:
        cpu = next(ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                   if ln.startswith("model name"))
    except (OSError, StopIteration):
        cpu = platform.processor() or platform.machine()
    return f"{cpu}, {os.cpu_count()} cores"


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 90 else f"{s / 60:.1f} min"


def render(readme: Readme, results: list[Ran]) -> str:
    """The README with every output region rewritten from ``results``."""
    by_name = {r.block.name: r for r in results}
    lines = list(readme.lines)
    for o in sorted(readme.outputs, key=lambda o: o.start, reverse=True):
        r = by_name.get(o.name)
        if r is None:  # not run (--only)
            continue
        region = [lines[o.start], "```text", *r.output.rstrip("\n").split("\n"), "```"]
        if not r.block.exact:
            day = datetime.date.today().isoformat()
            region.append(f"{STAMP_PREFIX} on {_machine()}, load {r.load:.1f} at the start (1-min average), {day}; "
                          f"the block ran {_duration(r.seconds)}.</sub>")
        lines[o.start:o.end] = region
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="run the small variants and compare the exact outputs (the test)")
    mode.add_argument("--list", action="store_true", help="list the marked blocks")
    mode.add_argument("--full", action="store_true", help="run every block as written (hours), then rewrite the README")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="run only these blocks (for trying a section out: the "
                    "blocks must not need the ones before them); rewrites only their outputs")
    ap.add_argument("--keep", type=Path, help="run in this folder (kept afterwards) instead of a temporary one")
    ap.add_argument("--quiet", action="store_true", help="do not echo the commands' output")
    a = ap.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # so a killed run takes its block's processes along
    try:
        readme = parse(README.read_text())
        if a.list:
            for b in readme.blocks:
                docs = "as written" if b.name in shown(readme) or not b.small else "small variant"
                print(f"{b.name:16s} README.md:{b.line:<5d} {'exact' if b.exact else '':6s} test: "
                      f"{'small variant' if b.small else 'as written':14s} make docs: {docs}")
            for line, why in readme.norun:
                print(f"{'(not run)':16s} README.md:{line:<5d} {why}")
            return 0
        echo = None if a.quiet else (lambda s: print(s, end="", flush=True))
        t0 = time.monotonic()
        results = run_all(small=a.check, check=a.check, readme=readme, echo=echo, figures=not a.check, keep=a.keep,
                          full=a.full, only=a.only)
        if not a.check:
            README.write_text(render(parse(README.read_text()), results))  # as it is now: it may have been edited meanwhile
            names = {r.block.name for r in results}
            n_out = sum(o.name in names for o in readme.outputs)
            n_fig = sum(f.after in names or (f.after is None and not a.only) for f in readme.figures)
            print(f"\nREADME.md: {n_out} output blocks and {n_fig} figures rewritten from {len(results)} blocks "
                  f"in {_duration(time.monotonic() - t0)}")
        else:
            print(f"\n{len(results)} blocks ran, exact outputs match ({_duration(time.monotonic() - t0)})")
    except ReadmeError as e:
        done = getattr(e, "results", None)
        if done and not (a.check or a.list):
            README.write_text(render(parse(README.read_text()), done))
            print(f"readme: the outputs of the {len(done)} blocks before it were written to README.md", file=sys.stderr)
        print(f"readme: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
