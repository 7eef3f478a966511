"""Run the command blocks of README.md and the manual's pages and write what they print into them (``make docs``);
check them (tests/test_readme.py).

The documents are README.md, then the pages of ``PAGES`` in that order; their blocks run in that order, as one
walkthrough, in one fresh folder, and block names are shared by all of them (``RECORDS`` are neither run nor checked).
HTML comments, which GitHub does not render, mark the blocks (docs/reproduction.md, "How these pages stay true"):

``<!-- run: NAME [exact] [timeout=SECONDS] [mask=REGEX ...] -->`` before a ``bash`` block (run as one ``bash -e``
    script, each command echoed as ``$ command``) or a ``python`` block (run by ``python -``). ``exact``: the output is
    deterministic and the test compares it with the output block, timings masked (``MASKS``, plus ``mask=``).
``<!-- norun: REASON -->`` before a block that is not run. Every ``bash`` and ``python`` block needs one of the two.
``<!-- small: NAME`` ... ``-->`` the block's small variant, a script with the same effect on smaller data: the test
    runs it instead of the block, and so does ``make docs`` for a block whose output no document shows (``--full``:
    every block as written).
``<!-- output: NAME -->`` where ``make docs`` writes what block NAME printed (a ``text`` block, the run folder shown
    as ``.``), followed unless NAME is ``exact`` by a line saying on what machine, at what load and when it ran.
``<!-- figure: docs/FILE.png from=PATH [after=NAME] [width=PIXELS] -->`` ``make docs`` copies PATH of the run folder
    to docs/FILE.png after block NAME (default: the last), at most ``width`` pixels wide (default 900).

The run folder holds copies of ``COPY`` and ``.venv``, links to the running virtual environment with a fresh install
marker (``make`` never re-installs), its ``bin`` first on PATH. Output is stdout and stderr as a terminal shows them,
without what a carriage return overwrote, progress bars or trailing blanks. A failing block stops the run naming its
document and line, with its last lines; ``make docs`` still writes the outputs of the blocks before it, into the
documents as they are by then (edits made meanwhile are kept).

    python tools/readme.py            # make docs: run the blocks, rewrite the documents and docs/*.png
    python tools/readme.py --full     # the same, every block as written (hours: the seed sweeps)
    python tools/readme.py --check    # small variants, compare exact outputs (the test: the blocks that train nothing)
    python tools/readme.py --list     # the blocks in the order they run
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
# The manual, in the order its blocks run after README.md's (the one list both tools and the tests read).
PAGES = ("docs/bring-up.md", "docs/training.md", "docs/importers.md", "docs/cli.md", "docs/artifact.md",
         "docs/simulator.md", "docs/models.md", "docs/api.md", "docs/robot-frame.md", "docs/arm.md",
         "docs/reproduction.md")
# Records of earlier rounds, quoted with the commits they ran on: not run, and their tables are not results.
RECORDS = ("docs/history.md",)
DOCS = ("README.md", *PAGES)
COPY = ("examples", "configs", "benchmarks", "Makefile", "pyproject.toml", "constraints.txt")
DEFAULT_TIMEOUT_S = 1800.0
# Volatile numbers masked before an exact comparison: durations and rates.
MASKS = (r"\d+(?:\.\d+)?(?=\s*(?:s|ms|us|µs|min|h)\b)", r"\d+(?:\.\d+)?(?=\s*[A-Za-z]+/s\b)")
RUNNABLE = ("bash", "sh", "shell", "console", "python")

_MARK = re.compile(r"^<!--\s*(run|norun|small|output|figure):\s*(.*?)\s*(-->)?\s*$")
_FENCE = re.compile(r"^(```+|~~~+)\s*([\w+-]*)")
STAMP_PREFIX = "<sub>Printed by `make docs`"


class ReadmeError(Exception):
    """A document's markers are malformed, or a block failed or printed something else."""


@dataclasses.dataclass
class Block:
    name: str
    script: str  # the commands as the document shows them
    line: int  # 1-based line of the marker
    doc: str = "README.md"
    lang: str = "bash"
    exact: bool = False
    timeout_s: float = DEFAULT_TIMEOUT_S
    masks: tuple[str, ...] = ()
    small: str | None = None

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}"

    def variant(self, small: bool) -> str:
        return self.small if small and self.small is not None else self.script


@dataclasses.dataclass
class Output:
    name: str
    doc: str
    start: int  # 0-based index of the marker line
    end: int  # index after the region (marker, fenced block, stamp line)
    text: str | None  # the fenced block's content, None when there is none yet


@dataclasses.dataclass
class Figure:
    dest: str
    src: str
    after: str | None
    width: int
    doc: str
    line: int


@dataclasses.dataclass
class Manual:
    lines: dict[str, list[str]]  # document -> its lines
    blocks: list[Block]  # in the order they run
    outputs: list[Output]
    figures: list[Figure]
    norun: list[tuple[str, int, str]]  # (document, line, reason)


def _attrs(text: str, where: str) -> tuple[str, dict[str, list[str]], set[str]]:
    try:
        words = shlex.split(text)
    except ValueError as e:
        raise ReadmeError(f"{where}: cannot parse {text!r}: {e}") from None
    if not words:
        raise ReadmeError(f"{where}: a marker needs a name")
    kv: dict[str, list[str]] = {}
    for w in words[1:]:
        if "=" in w:
            k, v = w.split("=", 1)
            kv.setdefault(k, []).append(v)
    return words[0], kv, {w for w in words[1:] if "=" not in w}


def _fence(lines: list[str], i: int, doc: str, skip_blank: bool = False) -> tuple[int, int, str] | None:
    """(index of the opening fence, index of the closing fence, info string) of a fenced block at line i."""
    while skip_blank and i < len(lines) and not lines[i].strip():
        i += 1
    m = _FENCE.match(lines[i]) if i < len(lines) else None
    if not m:
        return None
    j = i + 1
    while j < len(lines) and not lines[j].startswith(m.group(1)):
        j += 1
    if j >= len(lines):
        raise ReadmeError(f"{doc}:{i + 1}: unclosed code block")
    return i, j, m.group(2)


def _parse_doc(doc: str, lines: list[str], man: Manual, smalls: dict[str, tuple[str, str]]) -> None:
    covered: set[int] = set()  # opening fences of runnable blocks that carry a marker
    i = 0
    while i < len(lines):
        where = f"{doc}:{i + 1}"
        f = _fence(lines, i, doc)
        if f:  # markers inside code blocks are text
            if f[2] in RUNNABLE and i not in covered:
                raise ReadmeError(f"{where}: a {f[2]} block without `<!-- run: NAME -->` or `<!-- norun: REASON -->` "
                                  f"before it (tools/readme.py says how to mark it)")
            i = f[1] + 1
            continue
        m = _MARK.match(lines[i])
        if not m:
            i += 1
            continue
        kind, rest, closed = m.groups()
        if kind == "small":
            if closed:
                raise ReadmeError(f"{where}: `<!-- small: NAME` takes the script on the lines below it, closed by a line `-->`")
            j = next((j for j in range(i + 1, len(lines)) if lines[j].strip() == "-->"), None)
            if j is None:
                raise ReadmeError(f"{where}: `<!-- small: {rest}` is not closed by a line `-->`")
            name = (rest.split() or [""])[0]
            if name in smalls:
                raise ReadmeError(f"{where}: a second small variant of {name!r}")
            smalls[name] = (where, "\n".join(lines[i + 1:j]).strip() + "\n")
            i = j + 1
            continue
        if not closed:
            raise ReadmeError(f"{where}: a `<!-- {kind}: ... -->` marker must be one line")
        if kind in ("run", "norun"):
            f = _fence(lines, i + 1, doc, skip_blank=True)
            if f is None or f[2] not in RUNNABLE:
                raise ReadmeError(f"{where}: `<!-- {kind}: ... -->` must stand right before a ```bash or ```python block")
            covered.add(f[0])
            if kind == "norun":
                if not rest:
                    raise ReadmeError(f"{where}: `<!-- norun: REASON -->` needs a reason")
                man.norun.append((doc, i + 1, rest))
            else:
                name, kv, flags = _attrs(rest, where)
                unknown = (flags - {"exact"}) | (set(kv) - {"timeout", "mask"})
                if unknown:
                    raise ReadmeError(f"{where}: unknown run attribute(s) {sorted(unknown)}; known: exact, timeout=SECONDS, mask=REGEX")
                if any(b.name == name for b in man.blocks):
                    raise ReadmeError(f"{where}: a second run block named {name!r}")
                for rx in kv.get("mask", []):
                    re.compile(rx)
                man.blocks.append(Block(name, "\n".join(lines[f[0] + 1:f[1]]) + "\n", i + 1, doc,
                                        "python" if f[2] == "python" else "bash", "exact" in flags,
                                        float(kv.get("timeout", [DEFAULT_TIMEOUT_S])[0]), tuple(kv.get("mask", []))))
        elif kind == "output":
            name = _attrs(rest, where)[0]
            f = _fence(lines, i + 1, doc, skip_blank=True)
            end, content = (i + 1, None) if f is None or f[2] not in ("", "text") else (f[1] + 1, "\n".join(lines[f[0] + 1:f[1]]))
            if content is not None and end < len(lines) and lines[end].startswith(STAMP_PREFIX):
                end += 1
            man.outputs.append(Output(name, doc, i, end, content))
            i = end
            continue
        elif kind == "figure":
            dest, kv, _ = _attrs(rest, where)
            if not dest.startswith("docs/") or not dest.endswith(".png") or "from" not in kv:
                raise ReadmeError(f"{where}: `<!-- figure: docs/NAME.png from=PATH -->` (a PNG under docs/)")
            man.figures.append(Figure(dest, kv["from"][0], kv.get("after", [None])[0], int(kv.get("width", ["900"])[0]), doc, i + 1))
        i += 1


def parse(texts: dict[str, str] | str) -> Manual:
    """The marked blocks of the documents (``{document: text}``, in the order they run; a str is README.md)."""
    texts = {"README.md": texts} if isinstance(texts, str) else texts
    man = Manual({doc: text.split("\n") for doc, text in texts.items()}, [], [], [], [])
    smalls: dict[str, tuple[str, str]] = {}
    for doc, lines in man.lines.items():
        _parse_doc(doc, lines, man, smalls)
    blocks = {b.name: b for b in man.blocks}
    for name, (where, script) in smalls.items():
        if name not in blocks:
            raise ReadmeError(f"{where}: small variant of {name!r}, but no `<!-- run: {name} -->` block")
        blocks[name].small = script
    for o in man.outputs:
        if o.name not in blocks:
            raise ReadmeError(f"{o.doc}:{o.start + 1}: output of {o.name!r}, but no `<!-- run: {o.name} -->` block")
    for fig in man.figures:
        if fig.after is not None and fig.after not in blocks:
            raise ReadmeError(f"{fig.doc}:{fig.line}: figure after {fig.after!r}, but no such run block ({list(blocks)})")
    return man


def read(root: Path = ROOT) -> dict[str, str]:
    """The documents' texts, README.md first, then the pages in ``PAGES`` order."""
    return {doc: (root / doc).read_text() for doc in DOCS}


def shown(man: Manual) -> set[str]:
    """Names of the blocks whose printed output or files a document shows."""
    last = {man.blocks[-1].name} if man.blocks and any(f.after is None for f in man.figures) else set()
    return {o.name for o in man.outputs} | {f.after for f in man.figures if f.after} | last


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
    return out + ([cur.rstrip("\n")] if cur else [])


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


def to_script(script: str, lang: str = "bash") -> str:
    """A bash script that runs ``script``: a shell block printing ``$ command`` before each command and stopping at the
    first failure; a Python block as ``python -`` (its output is what it prints)."""
    if lang == "python":
        return f"set -eo pipefail\npython - <<'SONICSKIN_PYTHON'\n{script}SONICSKIN_PYTHON\n"
    parts = ["set -eo pipefail"]
    for cmd in commands(script):
        parts += [f"printf '%s\\n' {shlex.quote('$ ' + _shown(cmd))}", cmd]
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


def environment() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in (
        "MAKELEVEL", "MAKEFLAGS", "MFLAGS",  # under `make docs`: the blocks' make is a top-level make
        "PYTEST_CURRENT_TEST", "PYTEST_XDIST_WORKER", "PYTHONPATH")}
    env.update(PATH=str(_venv_bin()) + os.pathsep + env.get("PATH", ""), VIRTUAL_ENV=str(_venv_bin().parent),
               PYTHONUNBUFFERED="1", PYTHONDONTWRITEBYTECODE="1", TERM="dumb", COLUMNS="120", LC_ALL="C.UTF-8",
               # `make demo` must use the linked venv as installed, never re-install into it from the copy
               MAKEFLAGS="-o .venv/.installed", TQDM_DISABLE="1")
    return env


@dataclasses.dataclass
class Ran:
    block: Block
    output: str
    seconds: float
    load: float


def run_block(block: Block, folder: Path, small: bool, echo=None) -> Ran:
    """Run one block in ``folder``; its combined stdout/stderr (folder path as ``.``). Raises ReadmeError on failure."""
    load, t0 = os.getloadavg()[0], time.monotonic()
    proc = subprocess.Popen(["bash", "-c", to_script(block.variant(small), block.lang)], cwd=folder, env=environment(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)  # bytes: keep \r
    timer = threading.Timer(block.timeout_s, lambda: os.killpg(proc.pid, 9))
    timer.start()
    chunks = []
    try:
        for raw in proc.stdout:
            chunks.append(raw.decode("utf-8", errors="replace"))
            if echo:
                echo(chunks[-1])
        code = proc.wait()
    finally:
        timer.cancel()
        if proc.poll() is None:  # interrupted: take the block's processes along
            os.killpg(proc.pid, 9)
            proc.wait()
    seconds, out = time.monotonic() - t0, "".join(chunks)
    for p in sorted({str(folder), os.path.realpath(folder)}, key=len, reverse=True):
        out = out.replace(p + "/", "").replace(p, ".")
    out = clean(out)
    if code != 0:
        why = f"timed out after {block.timeout_s:g} s" if seconds >= block.timeout_s else f"exit code {code}"
        tail = "\n".join(out.rstrip().split("\n")[-25:])
        raise ReadmeError(f"{block.where}: block {block.name!r} ({'small variant' if small and block.small else 'as written'}) "
                          f"failed: {why}; its last lines:\n{tail}")
    return Ran(block, out.rstrip() + "\n", seconds, load)


def copy_figure(fig: Figure, folder: Path, root: Path = ROOT) -> Path:
    src = folder / fig.src
    if not src.is_file():
        raise ReadmeError(f"{fig.doc}:{fig.line}: figure {fig.dest}: {fig.src} was not written by the blocks")
    from PIL import Image

    dest = root / fig.dest
    dest.parent.mkdir(parents=True, exist_ok=True)
    with Image.open(src) as im:
        if im.width > fig.width:
            im = im.resize((fig.width, round(im.height * fig.width / im.width)), Image.LANCZOS)
        if im.mode == "RGBA" and im.getextrema()[3][0] == 255:  # opaque: an alpha channel adds bytes and nothing else
            im = im.convert("RGB")
        im.save(dest, optimize=True)
    return dest


def compare_exact(ran: Ran, man: Manual) -> None:
    """Fail when an exact block printed something other than its output block (volatile numbers masked)."""
    for o in man.outputs:
        if o.name == ran.block.name:
            want, got = mask(o.text or "", ran.block.masks), mask(ran.output, ran.block.masks)
            if want != got:
                diff = "\n".join(difflib.unified_diff(want.split("\n"), got.split("\n"), o.doc, "this commit", lineterm="", n=1))
                raise ReadmeError(f"{o.doc}:{o.start + 1}: the output of {ran.block.name!r} is stale; run `make docs`:\n{diff}")


def run_all(small: bool, check: bool, man: Manual | None = None, echo=None, figures: bool = False,
            keep: Path | None = None, full: bool = False, only: list[str] | None = None) -> list[Ran]:
    """Run every block in order in a fresh folder. ``small``: every small variant (the test); else the small variants
    of the blocks whose output no document shows (``full``: none). ``check``: compare the exact outputs."""
    man = man or parse(read())
    as_written = set() if small else {b.name for b in man.blocks} if full else shown(man)
    results: list[Ran] = []
    with tempfile.TemporaryDirectory(prefix="sonicskin-readme-") as tmp:
        folder = keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        prepare(folder)
        for b in man.blocks:
            if only and b.name not in only:
                continue
            use_small = b.name not in as_written
            if echo:
                echo(f"\n=== {b.name} ({'small variant' if use_small and b.small else 'as written'}, {b.where})\n")
            try:
                ran = run_block(b, folder, use_small, echo)
                if check and b.exact:
                    compare_exact(ran, man)
            except ReadmeError as e:
                e.results = results  # what ran before: make docs still writes their outputs
                raise
            results.append(ran)
            for fig in man.figures if figures else ():
                if fig.after == b.name or (fig.after is None and b is man.blocks[-1]):
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


def render(man: Manual, results: list[Ran]) -> dict[str, str]:
    """Every document's text with its output regions rewritten from ``results`` (regions of blocks not run are kept)."""
    by_name = {r.block.name: r for r in results}
    lines = {doc: list(ls) for doc, ls in man.lines.items()}
    for o in sorted(man.outputs, key=lambda o: o.start, reverse=True):
        r = by_name.get(o.name)
        if r is None:
            continue
        region = [lines[o.doc][o.start], "```text", *r.output.rstrip("\n").split("\n"), "```"]
        if not r.block.exact:
            region.append(f"{STAMP_PREFIX} on {_machine()}, load {r.load:.1f} at the start (1-min average), "
                          f"{datetime.date.today().isoformat()}; the block ran {_duration(r.seconds)}.</sub>")
        lines[o.doc][o.start:o.end] = region
    return {doc: "\n".join(ls) for doc, ls in lines.items()}


def write(results: list[Ran]) -> list[str]:
    """Write the outputs of ``results`` into the documents as they are now (they may have been edited meanwhile)."""
    texts = read()
    new = render(parse(texts), results)
    changed = [doc for doc in DOCS if new[doc] != texts[doc]]
    for doc in changed:
        (ROOT / doc).write_text(new[doc])
    return changed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="run the small variants and compare the exact outputs (the test)")
    mode.add_argument("--list", action="store_true", help="list the marked blocks in the order they run")
    mode.add_argument("--full", action="store_true", help="run every block as written (hours), then rewrite the documents")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="run only these blocks (for trying a section out: the "
                    "blocks must not need the ones before them); rewrites only their outputs")
    ap.add_argument("--keep", type=Path, help="run in this folder (kept afterwards) instead of a temporary one")
    ap.add_argument("--quiet", action="store_true", help="do not echo the commands' output")
    a = ap.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # so a killed run takes its block's processes along
    try:
        man = parse(read())
        if a.list:
            for b in man.blocks:
                docs = "as written" if b.name in shown(man) or not b.small else "small variant"
                print(f"{b.name:16s} {b.where:26s} {'exact' if b.exact else '':6s} test: "
                      f"{'small variant' if b.small else 'as written':14s} make docs: {docs}")
            for doc, line, why in man.norun:
                print(f"{'(not run)':16s} {f'{doc}:{line}':26s} {why}")
            return 0
        echo = None if a.quiet else (lambda s: print(s, end="", flush=True))
        t0 = time.monotonic()
        results = run_all(small=a.check, check=a.check, man=man, echo=echo, figures=not a.check, keep=a.keep,
                          full=a.full, only=a.only)
        if a.check:
            print(f"\n{len(results)} blocks ran, exact outputs match ({_duration(time.monotonic() - t0)})")
        else:
            changed = write(results)
            n_fig = sum(f.after in {r.block.name for r in results} or (f.after is None and not a.only) for f in man.figures)
            print(f"\n{', '.join(changed) or 'no document'} rewritten and {n_fig} figures copied from {len(results)} blocks "
                  f"in {_duration(time.monotonic() - t0)}")
    except ReadmeError as e:
        done = getattr(e, "results", None)
        if done and not (a.check or a.list):
            write(done)
            print(f"readme: the outputs of the {len(done)} blocks before it were written", file=sys.stderr)
        print(f"readme: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
