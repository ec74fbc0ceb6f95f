"""The cache trusts nothing executable from disk (issue 54).

A checksum beside an entry detects corruption, not tampering. The references here are the
disk and the process table: a crafted pickle whose checksum is right would create a file when
unpickled, a planted library creates one when loaded (an ELF constructor); neither file may
appear. A cache folder others may write into, and a signing key others may read, are refused
with exit 2 and one line.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from maglevgen.derive import memo
from maglevgen.errors import InputError, MaglevError
from maglevgen.infrastructure import cache

MODULE = "maglevgen.derive.conventions"  # a small source closure: the key's part


class _Touch:
    """Unpickling this creates ``path`` (what a crafted pickle would do, harmlessly)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (Path.touch, (self.path,))


@pytest.fixture
def private(tmp_path: Path, monkeypatch) -> Path:
    """An empty cache and a config folder of their own (the signing key made there)."""
    monkeypatch.setenv("MAGLEVGEN_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    cache._signing_key.cache_clear()
    cache._check_private.cache_clear()
    yield tmp_path
    cache._signing_key.cache_clear()
    cache._check_private.cache_clear()


def test_a_crafted_pickle_with_a_valid_checksum_does_not_run(private: Path) -> None:
    fired = private / "pickle-ran"
    payload = pickle.dumps(_Touch(fired))
    store = cache.DiskStore()
    path = store.path(MODULE, "crafted()")
    path.parent.mkdir(parents=True)
    # the old layout's checksum: sha256 of the payload, right for these bytes
    path.write_bytes(hashlib.sha256(payload).hexdigest().encode() + payload)
    assert store.get(MODULE, "crafted()") is memo.MISSING
    assert not fired.exists()
    # the same bytes signed with the user's key (read here from the key file) are the
    # user's own entry: loaded, and the pickle runs (the check is the key, nothing else)
    key = cache.key_file().read_bytes()
    import hmac

    path.write_bytes(hmac.new(key, payload, hashlib.sha256).hexdigest().encode() + payload)
    store.get(MODULE, "crafted()")
    assert fired.exists()


def test_the_key_is_private_and_outside_the_cache(private: Path) -> None:
    cache.sign(b"x")
    key = cache.key_file()
    assert key.is_file() and stat.S_IMODE(key.stat().st_mode) == 0o600
    root = cache.cache_root(None)
    assert not key.is_relative_to(root)
    assert stat.S_IMODE(root.stat().st_mode) == 0o700
    key.chmod(0o644)
    cache._signing_key.cache_clear()
    with pytest.raises(InputError, match=r"cache key .*cache.key: readable .*chmod 600"):
        cache.sign(b"x")


def test_a_cache_folder_others_may_write_is_refused(private: Path) -> None:
    root = cache.cache_root(None)
    root.chmod(0o777)
    cache._check_private.cache_clear()
    env = {**os.environ}
    done = subprocess.run([sys.executable, "-m", "maglevgen.cli", "trim"], env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == [
        f"maglevgen: error: cache folder {root}: writable by other users (mode 777); run "
        f"chmod go-w {root} or set MAGLEVGEN_CACHE to a private folder"]


_PLANTED = r"""
#include <stdio.h>
__attribute__((constructor)) static void planted(void) {
    FILE* f = fopen(MARK, "w");
    if (f) fclose(f);
}
int maglev_planted(void) { return 42; }
/* padding: the cache takes only libraries above 1 kB */
static const char pad[4096] = {1};
const char* maglev_pad(void) { return pad; }
"""


@pytest.mark.needs_cc
def test_a_planted_library_is_refused_with_a_clear_message(private: Path) -> None:
    from maglevgen.runtime.compile import compile_shared, trusted
    from maglevgen.runtime.library import SimulationLibrary

    src = private / "src"
    src.mkdir()
    (src / "lib.c").write_text("int maglev_one(void) { return 1; }\n"
                               "static const char pad[4096] = {1};\n"
                               "const char* maglev_pad(void) { return pad; }\n")
    lib = compile_shared([src / "lib.c"])
    assert trusted(lib)
    # a library with a constructor, compiled by hand, planted in its place with a checksum
    # that is right for its bytes (the old .sha256 file and in the signature file's place)
    fired = private / "constructor-ran"
    planted_c = private / "planted.c"
    planted_c.write_text(f'#define MARK "{fired}"\n' + _PLANTED)
    other = private / "planted.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-o", str(other), str(planted_c)], check=True)
    shutil.copyfile(other, lib)
    digest = hashlib.sha256(lib.read_bytes()).hexdigest() + "\n"
    lib.with_name(lib.name + ".sha256").write_text(digest)
    lib.with_name(lib.name + ".hmac").write_text(digest)
    assert not trusted(lib)
    with pytest.raises(MaglevError, match=rf"refusing to load {lib}: not a library "
                                          "maglevgen compiled in this cache"):
        SimulationLibrary(lib)
    steps: list[str] = []
    again = compile_shared([src / "lib.c"], progress=steps.append)
    assert again == lib and trusted(lib)
    assert any(f"cache entry {lib.name} is not signed by this user's cache key" in s
               for s in steps), steps
    assert lib.read_bytes() != other.read_bytes()
    assert not fired.exists()


def test_a_host_tuned_library_is_cached_per_cpu(tmp_path, monkeypatch):
    """-march=native means another CPU elsewhere: a cache folder shared by two machines must
    not hand one the other's library (SIGILL), so the key holds what the driver expands it to."""
    from maglevgen.runtime import compile as comp

    src = tmp_path / "a.c"
    src.write_text("int f(void) { return 1; }\n")
    gcc = shutil.which("gcc")
    assert gcc is not None
    expanded = comp._native_target(gcc)
    # the driver's own expansion names the CPU (gcc's cc1 -march=<cpu> -m<feature>...)
    assert any(t.startswith("-march=") and t != "-march=native" for t in expanded)
    assert not any("/" in t for t in expanded)  # no temporary file names: a stable key
    tuned = comp.HOST_TUNED_FLAGS
    here = comp._library_path(gcc, [src], tuned, tmp_path)
    monkeypatch.setattr(comp, "_native_target", lambda cc: ("-march=another-cpu",))
    assert comp._library_path(gcc, [src], tuned, tmp_path) != here
    # and a library not tuned to the CPU keeps one key whatever the CPU
    plain = comp._library_path(gcc, [src], comp.DEFAULT_FLAGS, tmp_path)
    monkeypatch.setattr(comp, "_native_target", lambda cc: ("-march=a-third-cpu",))
    assert comp._library_path(gcc, [src], comp.DEFAULT_FLAGS, tmp_path) == plain
