"""Run a command as if on another x86-64 CPU: another vendor, no AVX-512, other cache sizes.

    python scripts/cpu_disguise.py amd-zen3 -- python scripts/verify_lock.py --ignore-timings train_ae
    python scripts/cpu_disguise.py amd-zen3 --probe

Numerical libraries pick their kernels from what the CPUID instruction says: MKL by vendor (on AMD it
ignores its reproducibility branches but COMPATIBLE), oneDNN, NumPy, OpenBLAS, XLA and Embree by
instruction set, and some of them block their loops by cache size. To check on one machine that the
pipeline writes the same bits on the others, this runs a command with ``scripts/cpu_disguise.c`` preloaded
(compiled here with the system C compiler), which makes every CPUID of the process and of its children
answer as the disguise says:

- ``amd-zen3``: an AMD EPYC of the Zen 3 kind: vendor AuthenticAMD, AVX2 without AVX-512, AMD's cache
  leaves (L1d 32 KiB, L2 512 KiB, L3 32 MiB);
- ``amd-avx512``: the same with this CPU's AVX-512 left visible (as on Zen 4);
- ``intel-avx2``: an Intel CPU without AVX-512, its caches reported at Zen 3's sizes;
- ``intel-avx512``: an Intel CPU with this CPU's AVX-512 left visible (as on the Intel Xeons CI ran on).

On an Intel CPU the ``intel`` disguises change no vendor, on an AMD CPU the ``amd`` ones none: each
machine checks the other vendor's libraries' choices, and its own with and without AVX-512.

Only what CPUID reports changes: the instructions that run are this CPU's, so an AVX-512 kernel still runs
if a library picks one without asking. It needs Linux's CPUID faulting (the ``cpuid_fault`` flag in
/proc/cpuinfo; most Intel CPUs since Ivy Bridge and their VMs have it, some AMD VMs too: the Zen 4 of
2026-12-04 had it, the Zen 3 and Zen 5 here did not) and ``cc``. ``--probe`` prints the vendor and the
AVX-512 bit a process sees, read with the CPUID instruction itself.
"""

from __future__ import annotations

import argparse
import ctypes
import mmap
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

SOURCE = Path(__file__).resolve().with_suffix(".c")
DISGUISES = {"amd-zen3": "amd,noavx512", "amd-avx512": "amd", "intel-avx2": "intel,noavx512,smallcache",
             "intel-avx512": "intel"}

# x86-64 System V machine code of `void cpuid(uint32 leaf, uint32 subleaf, uint32 out[4])`:
# push rbx; mov eax, edi; mov ecx, esi; mov r8, rdx; cpuid; mov [r8], eax; mov [r8+4], ebx;
# mov [r8+8], ecx; mov [r8+12], edx; pop rbx; ret
_CPUID_CODE = bytes.fromhex("53 89f8 89f1 4989d0 0fa2 418900 41895804 41894808 4189500c 5b c3")


def supported() -> bool:
    """Whether this kernel and CPU offer CPUID faulting (what the shim needs)."""
    try:
        return "cpuid_fault" in Path("/proc/cpuinfo").read_text().split()
    except OSError:
        return False


def build(directory: Path) -> Path | None:
    """Compile the shim into ``directory`` -> the library's path, or None without a C compiler."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    library = Path(directory) / "cpu_disguise.so"
    subprocess.run([cc, "-shared", "-fPIC", "-O2", "-o", str(library), str(SOURCE), "-ldl"], check=True)
    return library


def environment(name: str, shim: Path, environ: dict[str, str]) -> dict[str, str]:
    """A copy of ``environ`` that runs its programs disguised as ``name`` (one of DISGUISES)."""
    if name not in DISGUISES:
        raise ValueError(f"unknown disguise {name!r}; choose from {sorted(DISGUISES)}")
    env = dict(environ)
    env["LD_PRELOAD"] = " ".join(filter(None, [str(shim), env.get("LD_PRELOAD", "")]))
    env["CPUID_DISGUISE"] = DISGUISES[name]
    return env


def cpuid(leaf: int, subleaf: int = 0) -> tuple[int, int, int, int]:
    """(eax, ebx, ecx, edx) of the CPUID instruction, run in this process (so a disguise applies)."""
    page = mmap.mmap(-1, mmap.PAGESIZE, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
    page.write(_CPUID_CODE)
    function = ctypes.CFUNCTYPE(None, ctypes.c_uint32, ctypes.c_uint32, ctypes.POINTER(ctypes.c_uint32))(
        ctypes.addressof(ctypes.c_char.from_buffer(page)))
    out = (ctypes.c_uint32 * 4)()
    function(leaf, subleaf, out)
    del function
    return tuple(int(v) for v in out)


def probe() -> dict[str, object]:
    """What this process's CPUID says: the vendor string and whether AVX-512 Foundation is there."""
    _, ebx, ecx, edx = cpuid(0)
    vendor = b"".join(v.to_bytes(4, "little") for v in (ebx, edx, ecx)).decode("ascii")
    return {"vendor": vendor, "avx512f": bool(cpuid(7, 0)[1] >> 16 & 1)}


def probe_command() -> list[str]:
    """A command that prints ``probe()`` as one JSON line, for a (disguised) child process."""
    return [sys.executable, "-c", f"import json, sys; sys.path.insert(0, {str(SOURCE.parent)!r}); "
            "import cpu_disguise; print(json.dumps(cpu_disguise.probe()))"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("disguise", choices=sorted(DISGUISES))
    parser.add_argument("--probe", action="store_true", help="print what a disguised process's CPUID says")
    parser.epilog = "then -- and the command to run"
    argv = sys.argv[1:] if argv is None else list(argv)
    split = argv.index("--") if "--" in argv else len(argv)
    args, command = parser.parse_args(argv[:split]), argv[split + 1:]
    if args.probe:
        command = probe_command()
    if not command:
        parser.error("give a command after --, or --probe")
    if not supported():
        parser.error("this CPU or kernel has no CPUID faulting (cpuid_fault in /proc/cpuinfo)")
    with tempfile.TemporaryDirectory(prefix="cpu_disguise_") as tmp:
        shim = build(Path(tmp))
        if shim is None:
            parser.error("no C compiler (cc) to build the shim")
        return subprocess.run(command, env=environment(args.disguise, shim, dict(os.environ))).returncode


if __name__ == "__main__":
    sys.exit(main())
