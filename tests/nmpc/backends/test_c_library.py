"""A C library that fails to build: one warning naming the compiler's own last line, and
``None`` (the caller's fallback runs).

Truth: a stand-in compiler (``$CC``) whose stderr and exit code are known.
"""

from __future__ import annotations

import logging

from aeromanip.nmpc.backends.c_library import CSources, load

STDERR = (
    "In file included from part.c:1:",
    "part.h:2:1: note: here",
    "part.c:3:5: error: the cause",
)


def test_a_failed_build_warns_once_with_the_compilers_last_line(monkeypatch, tmp_path, caplog):
    cc = tmp_path / "cc"
    cc.write_text("#!/bin/sh\n" + "".join(f"echo '{line}' >&2\n" for line in STDERR) + "exit 1\n")
    cc.chmod(0o755)
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path / "cache"))
    (tmp_path / "part.c").write_text("int part(void) { return 1; }\n")
    spec = CSources("part", tmp_path, ["part.c"], [], purpose="a test part", follows_codegen=False)
    with caplog.at_level(logging.WARNING):
        assert load(spec) is None
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "building a test part failed" in warnings[0]
    assert STDERR[-1] in warnings[0]
    assert not any(line in warnings[0] for line in STDERR[:-1])


def test_code_built_for_this_cpu_is_cached_per_cpu(monkeypatch, tmp_path):
    """A library built with ``-march=native`` is keyed by the CPU's model and flags too
    (a cache another machine shares does not hand it instructions it lacks); a portable
    one is the same entry on any CPU."""
    from aeromanip.nmpc.backends import c_library

    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path / "cache"))
    (tmp_path / "part.c").write_text("int part(void) { return 1; }\n")
    native = CSources("part", tmp_path, ["part.c"], [], cflags=("-O3", "-march=native"))
    portable = CSources("part", tmp_path, ["part.c"], [], cflags=("-O3",))
    entries = {}
    for cpu in ("model name: A\nflags: sse2", "model name: A\nflags: sse2 avx512f"):
        monkeypatch.setattr(c_library, "cpu_identity", lambda cpu=cpu: cpu)
        entries[cpu] = (
            c_library.entry_of(native, "gcc").lib,
            c_library.entry_of(portable, "gcc").lib,
        )
    (native_a, portable_a), (native_b, portable_b) = entries.values()
    assert native_a != native_b and portable_a == portable_b


def test_the_cpu_identity_names_this_machines_instruction_set():
    """On Linux, ``/proc/cpuinfo``'s flags (x86) or features (ARM), each line once."""
    from pathlib import Path

    from aeromanip.nmpc.backends.c_library import cpu_identity

    text = cpu_identity()
    assert text
    if Path("/proc/cpuinfo").exists():
        lines = text.splitlines()
        assert len(lines) == len(set(lines))
        assert any(line.startswith(("flags", "Features")) for line in lines)
