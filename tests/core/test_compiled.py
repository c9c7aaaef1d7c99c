"""The numba cache never breaks a command: unreadable, unwritable or unavailable caches are
warnings with a fallback (see :mod:`conformal_control.core.compiled`).

Each case runs a compiled kernel of the package in a fresh interpreter whose numba cache is a
temporary folder (``NUMBA_CACHE_DIR``), so the package's own ``__pycache__`` is never touched.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

CODE = """
import warnings
warnings.simplefilter("default")
from conformal_control.families.cbf.pyhypot import hypot_split
print(hypot_split(3.0, 4.0))
"""


#: kernels compiled at their first call (a short process would run them interpreted and never
#: touch numba's cache; see conformal_control.core.jit)
COMPILED = {"CONFORMAL_CONTROL_JIT": "always"}


def run(cache: Path, code: str = CODE) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), **COMPILED}
    return subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600
    )


def cache_files(cache: Path) -> list[Path]:
    return sorted(p for p in cache.rglob("*") if p.suffix in (".nbi", ".nbc"))


def test_a_truncated_or_corrupt_cache_is_compiled_again_and_rewritten(tmp_path: Path) -> None:
    cache = tmp_path / "numba"
    first = run(cache)
    assert first.returncode == 0 and first.stdout.strip() == "5.0", first.stderr
    files = cache_files(cache)
    assert any(p.suffix == ".nbi" for p in files) and any(p.suffix == ".nbc" for p in files)
    for i, p in enumerate(files):  # truncated index files, garbage data files
        p.write_bytes(p.read_bytes()[:20] if p.suffix == ".nbi" else b"\x80garbage" * (i + 1))
    second = run(cache)
    assert second.returncode == 0 and second.stdout.strip() == "5.0", second.stderr
    assert "CacheWarning" in second.stderr and "is unreadable" in second.stderr
    assert "Traceback" not in second.stderr
    third = run(cache)  # the cache was written afresh: loaded without a warning
    assert third.returncode == 0 and third.stdout.strip() == "5.0"
    assert "CacheWarning" not in third.stderr, third.stderr


def test_no_cache_location_compiles_in_memory(tmp_path: Path) -> None:
    """numba raised "cannot cache function ...: no locator available" at import."""
    code = (
        "import numba.core.caching as c\n"
        "c.CacheImpl._locator_classes = []  # as on a read-only install without a home\n" + CODE
    )
    res = run(tmp_path / "numba", code)
    assert res.returncode == 0 and res.stdout.strip() == "5.0", res.stderr
    assert "numba cannot cache" in res.stderr and "NUMBA_CACHE_DIR" in res.stderr


def test_a_cache_that_cannot_be_written_is_skipped(tmp_path: Path) -> None:
    code = (
        "import numba.core.caching as c\n"
        "def full(*a, **k):\n"
        "    raise OSError(28, 'No space left on device')\n"
        "c.IndexDataCacheFile._save_index = full\n" + CODE
    )
    res = run(tmp_path / "numba", code)
    assert res.returncode == 0 and res.stdout.strip() == "5.0", res.stderr
    assert "cannot be written" in res.stderr and "No space left" in res.stderr


def test_one_warning_per_kind_through_the_command_line(tmp_path: Path) -> None:
    """A whole corrupt cache gives one warning line, not one per compiled function."""
    cache = tmp_path / "numba"
    code = "import sys; from conformal_control.cli import main; sys.exit(main())"
    argv = ["run", "--frames", "5", "--no-plot", "--quiet"]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), **COMPILED}

    def cli(out: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-c", code, *argv, "--out", str(tmp_path / out)],
            env=env,
            capture_output=True,
            text=True,
            timeout=900,
        )

    assert cli("a").returncode == 0
    files = [p for p in cache.rglob("*.nbi")]
    assert len(files) > 3
    for p in files:
        p.write_bytes(b"\x80\x04not a pickle")
    res = cli("b")
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("warning: numba's cache of"), lines
