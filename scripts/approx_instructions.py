"""Which of the CPU's approximate instructions (``rcpps``, ``rsqrtps`` and their kin) a piece of Python runs.

    python scripts/approx_instructions.py [--lib libtorch_cpu] [--functions REGEX] [--setup CODE] -- CODE

Every other floating-point instruction gives the same bits on every x86-64 CPU; these approximate 1/x and
1/sqrt(x) to 12 bits (14 or 28 for the AVX-512 ones), each vendor its own way, so code that runs them may
give other bits on an Intel and an AMD CPU whatever the libraries are told (docs/reproducibility.md, Across
machines). MKL's vector math (VML), behind ``torch.sqrt`` on the CPU, is such code.

Runs ``--setup`` and then CODE in a child Python under the pipeline's pinned environment
(``tactile6d.runtime.instruction_sets``), with a one-shot gdb breakpoint on every such instruction of the
libraries whose file name contains ``--lib`` (repeatable; default ``libtorch_cpu``), set after the setup has
loaded them. ``--functions``: only the instructions inside the exported functions whose names match (much
faster on a library of hundreds of MB). Prints one JSON line per instruction CODE ran (library, offset,
function) and, last, ``{"executed": N, "sites": M, ...}``; exits 1 when N > 0. Machine code that libraries
generate at run time (oneDNN's and XLA's JIT kernels) is not covered: ``ONEDNN_JIT_DUMP=1`` writes oneDNN's.
Needs gdb and objdump (binutils), and a kernel that lets a process trace its child (ptrace).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile6d.runtime import instruction_sets  # noqa: E402  (imports nothing heavy)

# rcpps/rcpss/rsqrtps/rsqrtss (SSE), their VEX forms (v...), and AVX-512's vrcp14/vrsqrt14 (and the 28-bit
# AVX-512ER ones) on single and double precision.
APPROXIMATE = re.compile(r"^v?(rcp|rsqrt)(14|28)?(ps|ss|pd|sd)$")
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "tactile6d" / "approx_instructions"
START_S = 300.0  # for the child's setup (imports, data)


def instruction_sites(objdump_text: str) -> list[int]:
    """Offsets of the approximate instructions in ``objdump -d --no-show-raw-insn`` output."""
    sites = []
    for line in objdump_text.splitlines():
        address, colon, rest = line.partition(":")
        words = rest.split()
        if colon and words and APPROXIMATE.match(words[0]):
            try:
                sites.append(int(address.strip(), 16))
            except ValueError:
                continue
    return sites


def exported_functions(library: Path, pattern: str) -> list[tuple[int, int]]:
    """(start, end) offsets of the exported functions of ``library`` whose names match ``pattern``."""
    out = subprocess.run(["nm", "-D", "-S", "--defined-only", str(library)], capture_output=True, text=True,
                         check=True).stdout
    name = re.compile(pattern)
    spans = []
    for line in out.splitlines():
        fields = line.split()
        if len(fields) == 4 and fields[2] in "TtWw" and name.search(fields[3]):
            start, size = int(fields[0], 16), int(fields[1], 16)
            if size:
                spans.append((start, start + size))
    return sorted(spans)


def library_sites(library: Path, functions: str | None) -> list[int]:
    """The approximate instructions' offsets in ``library`` (in ``functions`` only, if given), cached by the
    file's path, size, time and the pattern: a whole libtorch_cpu.so takes minutes to disassemble."""
    st = library.stat()
    key = hashlib.sha1(f"{library}|{st.st_size}|{st.st_mtime_ns}|{functions}".encode()).hexdigest()[:16]
    cached = CACHE / f"{library.name}-{key}.json"
    if cached.exists():
        return json.loads(cached.read_text())
    if functions is None:
        sites = instruction_sites(_disassembly(library))
    else:
        spans = exported_functions(library, functions)
        sites = []
        for start, end in _clusters(spans):  # one objdump per run of nearby functions: each call reads the file
            sites += instruction_sites(_disassembly(library, start, end))
        sites = [site for site in sites if any(a <= site < b for a, b in spans)]
    CACHE.mkdir(parents=True, exist_ok=True)
    cached.write_text(json.dumps(sites))
    return sites


def _disassembly(library: Path, start: int | None = None, end: int | None = None) -> str:
    bounds = [] if start is None else [f"--start-address={start:#x}", f"--stop-address={end:#x}"]
    return subprocess.run(["objdump", "-d", "--no-show-raw-insn", *bounds, str(library)], capture_output=True,
                          text=True, check=True).stdout


def _clusters(spans: list[tuple[int, int]], gap: int = 1 << 16) -> list[tuple[int, int]]:
    """Sorted (start, end) spans merged where less than ``gap`` bytes apart."""
    merged: list[list[int]] = []
    for start, end in spans:
        if merged and start - merged[-1][1] < gap:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([start, end])
    return [(a, b) for a, b in merged]


def mapped_libraries(pid: int, names: list[str]) -> dict[Path, int]:
    """Library file -> load address (its mapping at file offset 0) of the libraries of process ``pid``
    whose file name contains one of ``names``."""
    found: dict[Path, int] = {}
    for line in Path(f"/proc/{pid}/maps").read_text().splitlines():
        fields = line.split()
        if len(fields) < 6 or int(fields[2], 16) != 0:
            continue
        path = Path(fields[5])
        if any(n in path.name for n in names) and path not in found:
            found[path] = int(fields[0].split("-")[0], 16)
    return found


def gdb_commands(breakpoints: list[tuple[int, int, int]], go_file: Path) -> str:
    """A gdb script: a one-shot breakpoint at each (library index, offset, address) that prints where it
    stopped and goes on; then the child is let go and run to its end."""
    lines = ["set pagination off", "set confirm off", "set breakpoint pending off"]
    for lib, offset, address in breakpoints:
        lines += [f"tbreak *{address:#x}", "commands", "silent", f'printf "HIT {lib} {offset:#x} "',
                  "info symbol $pc", "continue", "end"]
    lines += [f"shell touch {go_file}", "continue", "quit"]
    return "\n".join(lines) + "\n"


def child_program(setup: str, code: str, ready: Path, go: Path) -> str:
    return "\n".join([
        "import sys, time, pathlib",
        f"sys.path[:0] = [{str(ROOT)!r}]",
        setup,
        f"pathlib.Path({str(ready)!r}).touch()",
        f"while not pathlib.Path({str(go)!r}).exists(): time.sleep(0.05)",
        code,
    ])


def probe(code: str, setup: str = "", libraries: tuple[str, ...] = ("libtorch_cpu",),
          functions: str | None = None) -> dict:
    """Run ``setup`` then ``code`` in a child under the breakpoints -> {"hits": [...], "sites": M,
    "libraries": [...]}. Raises RuntimeError when the child or gdb fails."""
    with tempfile.TemporaryDirectory() as tmp:
        ready, go, script = Path(tmp, "ready"), Path(tmp, "go"), Path(tmp, "child.py")
        script.write_text(child_program(setup, code, ready, go))
        env = instruction_sets.pinned_environment(dict(os.environ, OPENBLAS_NUM_THREADS="1"))
        child = subprocess.Popen([sys.executable, str(script)], env=env, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + START_S
            while not ready.exists():
                if child.poll() is not None:
                    raise RuntimeError(f"the child ended during its setup: {child.stderr.read()}")
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the child's setup took over {START_S:g} s")
                time.sleep(0.05)
            libs = mapped_libraries(child.pid, list(libraries))
            if not libs:
                raise RuntimeError(f"no library of the child's matches {list(libraries)}: load it in --setup")
            paths = list(libs)
            breakpoints = [(i, offset, libs[path] + offset) for i, path in enumerate(paths)
                           for offset in library_sites(path, functions)]
            commands = Path(tmp, "commands.gdb")
            commands.write_text(gdb_commands(breakpoints, go))
            gdb = subprocess.run(["gdb", "-q", "-batch", "-p", str(child.pid), "-x", str(commands)],
                                 capture_output=True, text=True)
            stdout, stderr = child.communicate(timeout=3600)
        finally:
            if child.poll() is None:
                child.kill()
        if child.returncode != 0 or not go.exists():
            raise RuntimeError(f"the child failed (status {child.returncode}): {stderr.strip()[-2000:]}\n"
                               f"gdb: {gdb.stdout[-1000:]}{gdb.stderr[-1000:]}")
    hits = []
    for line in gdb.stdout.splitlines():
        if line.startswith("HIT "):
            _, lib, offset, *where = line.split()
            hits.append({"library": paths[int(lib)].name, "offset": offset,
                         "function": where[0] if where and where[0] != "No" else None})
    return {"hits": hits, "sites": len(breakpoints), "libraries": [str(p) for p in paths]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--lib", action="append", default=None,
                        help="a library file name's part (repeatable; default libtorch_cpu)")
    parser.add_argument("--functions", default=None, help="only inside the exported functions matching this regex")
    parser.add_argument("--setup", default="import torch", help="run before the breakpoints are set (imports, data)")
    parser.add_argument("code", help="the Python code to probe")
    args = parser.parse_args(argv)
    result = probe(args.code, args.setup, tuple(args.lib or ["libtorch_cpu"]), args.functions)
    for hit in result["hits"]:
        print(json.dumps(hit))
    print(json.dumps({"executed": len(result["hits"]), "sites": result["sites"], "libraries": result["libraries"]}))
    return 1 if result["hits"] else 0


if __name__ == "__main__":
    sys.exit(main())
