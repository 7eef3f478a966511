"""The measured results of README.md and the manual: each one the stored stdout of one registered command
(``make results``, ``make docs``).

A number in a results table is only as good as the run that printed it. So every measured table, figure and
benchmark figure of README.md and the manual's pages (``readme.DOCS``) is a *result*: a command registered in
``docs/results/index.yaml``, run from the repository root with the project's virtual environment first on PATH,
whose **stdout is exactly the block the document shows** (logs and progress go to stderr). Running it stores
``docs/results/NAME.json``: the block, the command, the commit and whether the tree was clean, a digest of the code
it ran, the machine, the load at the start, the date, wall and CPU time, and copies of the figures it wrote
(``docs/*.png``). A document marks where a result goes (any document; each result in exactly one place)::

    <!-- result: NAME -->
    ... written by ``python tools/results.py render`` (part of ``make docs``): the stored block, then one line
    saying what command measured it, at which commit, on what machine, at what load, when and how long ...
    <!-- /result -->

and ``tests/test_results.py`` fails when a block differs from its stored result, when a stored result was measured
by another command than the registered one, or when a table or ``text`` block of a document is neither a result,
a ``make docs`` output (tools/readme.py) nor marked ``<!-- spec: WHY -->`` (parameters, formats and limits that are
not measurements). ``status`` lists the results whose code changed since they were measured.

    python tools/results.py list               # the registered results, their cost and when they were measured
    python tools/results.py run probe seeds    # measure (long: see each entry's cost), store, then render
    python tools/results.py run --all          # every result (make results: hours on 2 cores)
    python tools/results.py render             # write the stored results into the documents (make docs does this)
    python tools/results.py status             # which results ran on code that has changed since
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme import DOCS, ROOT, read  # noqa: E402  (one list of the documents for both generators)
from readme import _machine as machine  # noqa: E402  (one description of the machine for both generators)

STORE = ROOT / "docs" / "results"
INDEX = STORE / "index.yaml"
# The code a result depends on: a change here may change what a result's command prints.
CODE = ("sonicskin", "models", "training", "export", "configs", "benchmarks", "pyproject.toml", "constraints.txt")

_OPEN = re.compile(r"^<!--\s*result:\s*([\w.-]+)\s*-->\s*$")
_CLOSE = "<!-- /result -->"
_SPEC = re.compile(r"^<!--\s*spec:\s*\S.*-->\s*$")
STAMP_PREFIX = "<sub>Measured by `python tools/results.py run"


class ResultError(Exception):
    """A result is missing, stale or malformed, or its command failed."""


def index() -> dict[str, dict]:
    reg = yaml.safe_load(INDEX.read_text())
    if not isinstance(reg, dict):
        raise ResultError(f"{INDEX}: a mapping NAME -> {{run: ..., cost: ..., about: ...}}")
    for name, e in reg.items():
        if not isinstance(e, dict) or not isinstance(e.get("run"), str) or not isinstance(e.get("cost"), str):
            raise ResultError(f"{INDEX}: {name}: needs `run` (the shell command) and `cost` (how long it takes)")
        unknown = set(e) - {"run", "cost", "about", "format", "figures", "of_the_commit"}
        if unknown:
            raise ResultError(f"{INDEX}: {name}: unknown key(s) {sorted(unknown)}")
        if e.get("format", "markdown") not in ("markdown", "text"):
            raise ResultError(f"{INDEX}: {name}: format is markdown or text")
    return reg


def stored(name: str) -> dict | None:
    p = STORE / f"{name}.json"
    return json.loads(p.read_text()) if p.is_file() else None


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False).stdout.strip()


def code_digest() -> str:
    """sha256 over the tracked files of ``CODE`` (path and bytes of the working tree)."""
    h = hashlib.sha256()
    for path in sorted(_git("ls-files", "--", *CODE).splitlines()):
        p = ROOT / path
        if p.is_file():
            h.update(path.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 90 else f"{s / 60:.0f} min" if s < 5400 else f"{s / 3600:.1f} h"


def environment() -> dict[str, str]:
    env = dict(os.environ)
    bin_ = str(Path(sys.executable).parent)
    env.update(PATH=bin_ + os.pathsep + env.get("PATH", ""), VIRTUAL_ENV=str(Path(bin_).parent), PYTHONUNBUFFERED="1",
               TQDM_DISABLE="1", LC_ALL="C.UTF-8", COLUMNS="120")
    for k in ("MAKELEVEL", "MAKEFLAGS", "MFLAGS", "PYTEST_CURRENT_TEST", "PYTEST_XDIST_WORKER", "PYTHONPATH"):
        env.pop(k, None)
    return env


def run(name: str, entry: dict, log=None) -> dict:
    """Run one result's command in the repository root; store and return its record."""
    log = log or (lambda s: print(s, file=sys.stderr, flush=True))
    commit, dirty = _git("rev-parse", "HEAD"), bool(_git("status", "--porcelain", "--", *CODE))
    digest = code_digest()
    load = os.getloadavg()[0]
    started = datetime.datetime.now(datetime.timezone.utc)
    log(f"results: {name}: {entry['run'].strip()}  ({entry['cost']})")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    proc = subprocess.run(["bash", "-eo", "pipefail", "-c", entry["run"]], cwd=ROOT, env=environment(),
                          stdout=subprocess.PIPE, stderr=None, text=True)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise ResultError(f"{name}: the command failed (exit code {proc.returncode}); nothing stored")
    out = "\n".join(ln.rstrip() for ln in proc.stdout.strip("\n").split("\n"))
    if not out.strip():
        raise ResultError(f"{name}: the command printed nothing on stdout; nothing stored")
    figures = {}
    for dest, src in (entry.get("figures") or {}).items():
        if not (ROOT / src).is_file():
            raise ResultError(f"{name}: the command did not write {src}; nothing stored")
        shutil.copy2(ROOT / src, ROOT / dest)
        figures[dest] = hashlib.sha256((ROOT / dest).read_bytes()).hexdigest()
    rec = {"name": name, "run": entry["run"], "stdout": out, "format": entry.get("format", "markdown"),
           "figures": figures, "commit": commit, "dirty": dirty, "code_digest": digest, "machine": machine(),
           "load": round(load, 1), "started": started.isoformat(timespec="seconds"), "wall_s": round(wall, 1),
           "cpu_s": round((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), 1)}
    STORE.mkdir(parents=True, exist_ok=True)
    tmp = STORE / f".{name}.json.tmp"
    tmp.write_text(json.dumps(rec, indent=1, ensure_ascii=False) + "\n")
    tmp.replace(STORE / f"{name}.json")
    log(f"results: {name}: stored docs/results/{name}.json ({_duration(wall)} wall, {_duration(rec['cpu_s'])} CPU)")
    return rec


STALE = ("**The code has changed since this run** (`python tools/results.py status`): these numbers are of the commit "
         "named below, not of the code beside them.")


def block(rec: dict, stale: bool = False) -> list[str]:
    """The document lines of one stored result (between its markers); ``stale``: its code has changed since (said
    above the stamp, so a page never shows old numbers as current)."""
    body = rec["stdout"].split("\n")
    if rec["format"] == "text":
        body = ["```text", *body, "```"]
    day = rec["started"][:10]
    where = f"commit {rec['commit'][:7]}" + (" plus uncommitted changes" if rec["dirty"] else "")
    return [*body, "", *([STALE, ""] if stale else []),
            f"{STAMP_PREFIX} {rec['name']}` ({where}) on {rec['machine']}, load {rec['load']:.1f} at the start "
            f"(1-min average), {day}; it ran {_duration(rec['wall_s'])} ({_duration(rec['cpu_s'])} of CPU).</sub>"]


def _stale(rec: dict, now: str) -> bool:
    return rec["code_digest"] != now or bool(rec["dirty"])


def regions(lines: list[str], doc: str = "README.md") -> list[tuple[str, int, int]]:
    """(name, index of the opening marker, index of the closing marker) of every result region of one document."""
    out, open_ = [], None
    for i, ln in enumerate(lines):
        m = _OPEN.match(ln)
        if m:
            if open_:
                raise ResultError(f"{doc}:{i + 1}: result {m.group(1)!r} opens inside {open_[0]!r} (close it with {_CLOSE})")
            open_ = (m.group(1), i)
        elif ln.strip() == _CLOSE:
            if not open_:
                raise ResultError(f"{doc}:{i + 1}: {_CLOSE} without an opening `<!-- result: NAME -->`")
            out.append((*open_, i))
            open_ = None
    if open_:
        raise ResultError(f"{doc}:{open_[1] + 1}: result {open_[0]!r} is not closed by a line {_CLOSE}")
    return out


def render(text: str, doc: str = "README.md", *, stale: bool = True) -> str:
    """``text`` (one document) with every result region rewritten from its stored record (``stale``: with the line
    saying when its code has changed since)."""
    reg, now = index(), code_digest() if stale else ""
    lines = text.split("\n")
    for name, start, end in reversed(regions(lines, doc)):
        if name not in reg:
            raise ResultError(f"{doc}:{start + 1}: result {name!r} is not registered in docs/results/index.yaml")
        rec = stored(name)
        lines[start + 1:end] = (block(rec, stale and _stale(rec, now)) if rec else
                                [f"*(not measured yet: `python tools/results.py run {name}`)*"])
    return "\n".join(lines)


def problems(texts: dict[str, str] | str) -> list[str]:
    """What the test checks, over the documents (``{document: text}``; a str is README.md): stored results match their
    commands, each result is shown once and as stored, and every table and ``text`` block is a result, a ``make docs``
    output or marked as a spec."""
    texts = {"README.md": texts} if isinstance(texts, str) else texts
    reg, out, seen = index(), [], {}
    for doc, text in texts.items():
        lines = text.split("\n")
        try:
            spans = regions(lines, doc)
        except ResultError as e:
            out.append(str(e))
            continue
        for name, start, _ in spans:
            where = f"{doc}:{start + 1}"
            if name in seen:
                out.append(f"{where}: result {name!r} is shown twice (also at {seen[name]}); show it in one place and link there")
            seen[name] = where
            rec = stored(name) if name in reg else None
            if name in reg and rec is None and not reg[name].get("of_the_commit"):
                # (a result `of_the_commit`, CI's own time, can only be measured once the commit exists)
                out.append(f"{where}: result {name!r} was never measured: python tools/results.py run {name}")
            if name in reg and rec is not None and rec["run"] != reg[name]["run"]:
                out.append(f"{where}: result {name!r} was measured by another command than the registered one: "
                           f"python tools/results.py run {name}")
            for dest, sha in (rec or {}).get("figures", {}).items():
                p = ROOT / dest
                if not p.is_file() or hashlib.sha256(p.read_bytes()).hexdigest() != sha:
                    out.append(f"{dest}: not the figure result {name!r} stored; python tools/results.py run {name}")
        try:  # as rendered, with or without the stale line (the code may change after a render)
            if text not in (render(text, doc), render(text, doc, stale=False)):
                out.append(f"{doc}: a result block differs from its stored result: run `python tools/results.py render`")
        except ResultError as e:
            out.append(str(e))
        out += _unmarked(lines, {i for _, s, e in spans for i in range(s, e + 1)}, doc)
    return out


def _unmarked(lines: list[str], inside: set[int], doc: str) -> list[str]:
    """Tables and plain/``text`` blocks outside result regions that are neither an output nor marked as a spec."""
    out, i, prev = [], 0, ""
    while i < len(lines):
        ln = lines[i]
        f = re.match(r"^\s*(```+|~~~+)\s*([\w+-]*)", ln)
        if f:
            j = i + 1
            while j < len(lines) and not lines[j].lstrip().startswith(f.group(1)):
                j += 1
            if f.group(2) in ("", "text") and i not in inside and not _covered(lines, i, ("output", "spec")):
                out.append(f"{doc}:{i + 1}: a text or plain block that is neither a result (<!-- result: NAME -->), a make docs "
                           f"output (<!-- output: NAME -->) nor marked <!-- spec: WHY -->")
            i, prev = j + 1, ""
            continue
        if ln.startswith("|") and not prev.startswith("|") and i not in inside and not _covered(lines, i, ("spec",)):
            out.append(f"{doc}:{i + 1}: a table that is neither a result (<!-- result: NAME -->) nor marked "
                       f"<!-- spec: WHY --> (parameters, not measurements)")
        prev = ln
        i += 1
    return out


def _covered(lines: list[str], i: int, kinds: tuple[str, ...]) -> bool:
    """Whether the nearest non-blank line above line i is a marker of one of ``kinds``."""
    j = i - 1
    while j >= 0 and not lines[j].strip():
        j -= 1
    return j >= 0 and bool(re.match(r"^<!--\s*(" + "|".join(kinds) + r"):", lines[j]))


def shown() -> dict[str, str]:
    """Where each result is shown: NAME -> document."""
    return {name: doc for doc, text in read().items() for name, _, _ in regions(text.split("\n"), doc)}


def render_all() -> list[str]:
    """Write the stored results into every document; the documents changed."""
    changed = []
    for doc, text in read().items():
        new = render(text, doc)
        if new != text:
            (ROOT / doc).write_text(new)
            changed.append(doc)
    return changed


def status() -> list[str]:
    reg, now, out = index(), code_digest(), []
    for name, e in reg.items():
        rec = stored(name)
        if rec is None:
            out.append(f"{name:14s} never measured ({e['cost']})")
            continue
        state = "current code" if rec["code_digest"] == now and not rec["dirty"] else "code changed since"
        if rec["run"] != e["run"]:
            state = "command changed since: re-run"
        out.append(f"{name:14s} {rec['started'][:16]} commit {rec['commit'][:7]}  {_duration(rec['wall_s']):>7s}  {state}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="measure results (long), store them, write them into the documents")
    r.add_argument("names", nargs="*", metavar="NAME")
    r.add_argument("--all", action="store_true", help="every registered result")
    r.add_argument("--keep-going", action="store_true", help="go on with the next result when one fails")
    sub.add_parser("render", help="write the stored results into README.md and the manual's pages")
    sub.add_parser("check", help="what tests/test_results.py checks")
    sub.add_parser("status", help="when each result was measured and whether its code changed since")
    sub.add_parser("list", help="the registered results")
    a = ap.parse_args(argv)
    try:
        reg = index()
        if a.cmd == "list":
            for name, e in reg.items():
                print(f"{name:14s} {e['cost']:28s} {e.get('about', '')}")
        elif a.cmd == "status":
            print("\n".join(status()))
        elif a.cmd == "check":
            errs = problems(read())
            print("\n".join(errs) or f"results of {len(DOCS)} documents: ok")
            return 1 if errs else 0
        else:
            if a.cmd == "run":
                names = list(reg) if a.all else a.names
                unknown = [n for n in names if n not in reg]
                if unknown or not names:
                    raise ResultError(f"unknown result(s) {unknown}; registered: {', '.join(reg)}" if unknown
                                      else "name the results to run, or --all")
                failed = []
                for n in names:
                    try:
                        run(n, reg[n])
                    except ResultError as e:
                        if not a.keep_going:
                            raise
                        failed.append(n)
                        print(f"results: error: {e}", file=sys.stderr)
                if failed:
                    print(f"results: failed: {' '.join(failed)}", file=sys.stderr)
            for doc in render_all():
                print(f"results: {doc} rewritten", file=sys.stderr)
    except ResultError as e:
        print(f"results: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
