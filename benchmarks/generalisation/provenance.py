"""Where a benchmark's answers come from: the case files' digests and the machine.

The same code has answered the same case differently on two machines of one kind (2-core
AMD EPYC with AVX-512): seed 41 case 4 of the hidden part claimed its stop at once on one
and after a wrong place on the other; seed 42 case 12's linear revision validated at
15.4 % on the machine that ran the draw and at 15.8 % on the next, with the same code
and the same noise floor, and without moving here under either BLAS kernel, one or two
threads, numpy's AVX-512 paths switched off, or a 1e-7 relative perturbation of the
records. Whether the case files or the computation differed could not be told
afterwards. So the generation records a digest of every case file in the index, and the
answers record the digest of the file they read and the machine that read it: a
difference between two runs is then either in the files (digests differ) or in the
computation (same digests, machines named).
"""

from __future__ import annotations

import hashlib
import os
import platform
from importlib import metadata
from pathlib import Path

import numpy as np

DIGEST_CHARS = 16
"""Hexadecimal characters of SHA-256 kept (64 bits: no collision among a benchmark's
files)."""

LIBRARIES = ("numpy", "scipy", "numba", "llvmlite")
"""Packages whose versions shape the numbers."""

BLAS_SETTINGS = ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS")


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes, the first :data:`DIGEST_CHARS` hex digits."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()[:DIGEST_CHARS]


def _cpu() -> str:
    """The CPU's model name, family and model (Linux), else the platform's word."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or platform.machine()
    fields = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
        if not line.strip():   # the first processor is enough
            break
    return (f"{fields.get('model name', platform.machine())}, family "
            f"{fields.get('cpu family', '?')} model {fields.get('model', '?')}")


def _simd() -> list[str]:
    """The SIMD extensions numpy dispatches to on this CPU."""
    features = np._core._multiarray_umath.__cpu_features__
    return sorted(name for name, found in features.items() if found and name.startswith("AVX"))


def machine() -> dict:
    """What the numbers may depend on besides the code and the files: the CPU, numpy's
    SIMD paths, the numerical libraries' versions and the BLAS settings."""
    return {"cpu": _cpu(), "cores": os.cpu_count(), "simd": _simd(),
            "libraries": {name: metadata.version(name) for name in LIBRARIES},
            "blas": {name: os.environ.get(name, "(unset)") for name in BLAS_SETTINGS}}


def provenance_words(index: dict, answers: dict[str, dict]) -> str:
    """One paragraph for a results file: whether every answered file is the one drawn
    (the index's digests), and the machine(s) that answered."""
    drawn = index.get("digests", {})
    read = {case: a.get("provenance", {}).get("digest") for case, a in answers.items()}
    if not drawn or not any(read.values()):
        files = "Case files: no digests recorded (drawn or answered before digests were kept)."
    else:
        differ = sorted(c for c, d in read.items() if drawn.get(c) != d)
        files = (f"Case files: the {len(read)} answered are the ones drawn (SHA-256 digests "
                 "in the index)." if not differ else
                 f"Case files: {len(differ)} answered file(s) differ from the ones drawn: "
                 + ", ".join(differ) + ".")
    machines = {repr(a["provenance"]["machine"]) for a in answers.values()
                if "provenance" in a}
    if len(machines) == 1:
        only = next(a["provenance"]["machine"] for a in answers.values() if "provenance" in a)
        where = (f" Answered on {only['cpu']} ({only['cores']} cores), numpy SIMD "
                 f"{'/'.join(only['simd']) or 'baseline'}, "
                 + ", ".join(f"{k} {v}" for k, v in only["libraries"].items()) + ", "
                 + ", ".join(f"{k}={v}" for k, v in only["blas"].items()) + ".")
    else:
        where = f" Answered on {len(machines)} machine settings." if machines else ""
    return files + where
