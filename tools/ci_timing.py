"""Time CI on a clean clone of HEAD: ``bash .ci/run`` (the venv install, ``make test``, ``make deploy-check``).

Prints, on stdout, the README's table of how long each step took (the install is timed apart: issue 18's
"make test <= 6 minutes" is with the venv already built) and the CPU time of the whole suite (issue 37: <= 12
CPU-minutes); the whole log goes to stderr. Exit code 1 when CI
fails. ``python tools/results.py run ci`` stores it for the README.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="sonicskin-ci-") as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=clone, capture_output=True, text=True).stdout.strip()
        proc = subprocess.Popen(["bash", ".ci/run"], cwd=clone, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        log = []
        for ln in proc.stdout:
            log.append(ln)
            sys.stderr.write(ln)
        code = proc.wait()
    text = "".join(log)
    secs = {m.group(1): int(m.group(2)) for m in re.finditer(r"^make ([\w-]+): (\d+) s$", text, re.M)}
    summaries = re.findall(r"^=*\s*(\d+ passed[^\n]*?) in ([\d.]+)s", text, re.M)
    if code != 0 or not {"install", "test", "deploy-check"} <= set(secs):
        print(f"CI failed on a clean clone of {commit} (exit code {code})")
        return 1
    parallel = f"{summaries[0][0]} in {float(summaries[0][1]):.0f} s" if summaries else "?"
    serial = f"{summaries[1][0]} in {float(summaries[1][1]):.0f} s" if len(summaries) > 1 else "?"
    cpu = re.search(r"^make test CPU: (\d+) s user, (\d+) s system$", text, re.M)
    cpu = f"{(int(cpu.group(1)) + int(cpu.group(2))) / 60:.1f} CPU-minutes" if cpu else "CPU not measured"
    print(f"| `bash .ci/run` on a clean clone of {commit} | wall |")
    print("|---|---|")
    print(f"| `make install` (the venv: not part of the 6-minute target) | {secs['install']} s |")
    print(f"| `make test` (parallel step: {parallel}; serial step: {serial}; {cpu}) | **{secs['test']} s** |")
    print(f"| `make deploy-check` (torch-free wheel in a fresh venv) | {secs['deploy-check']} s |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
