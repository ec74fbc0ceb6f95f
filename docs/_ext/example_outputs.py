"""The example scripts' outputs as the documentation site shows them: stored, and checked.

Running every script of examples/ takes minutes (the FMU's compile, the Monte Carlo runs), too
long for each docs build, so the site shows what a run printed and drew, stored in
docs/_examples/<script>/ (``output.txt``: stdout; the PNGs the script wrote, under their paths
in ``example_output/``). ``tests/test_examples.py`` runs each script as a user does and checks
that its stdout and figures are the stored ones, so the page cannot go stale.

    python docs/_ext/example_outputs.py [SCRIPT ...]     # (make example-outputs) store them
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"
STORE = REPO / "docs" / "_examples"
DEFAULT_OUT = "example_output"  # every script's default output folder, relative to its cwd


@dataclass(frozen=True)
class Run:
    """One run of a script: its exit code, stdout, stderr and the PNGs it wrote (path
    relative to ``example_output/`` -> file)."""

    returncode: int
    stdout: str
    stderr: str
    figures: dict[str, Path]


def scripts() -> list[Path]:
    return sorted(EXAMPLES.glob("*.py"))


def run(script: Path, cwd: Path, timeout: float = 900) -> Run:
    """``python examples/<script>`` with no argument, in ``cwd``, as the page says it is run
    (so the paths it prints are the ones a user sees)."""
    proc = subprocess.run([sys.executable, str(script)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout)
    out = cwd / DEFAULT_OUT
    figures = {p.relative_to(out).as_posix(): p for p in sorted(out.rglob("*.png"))}
    return Run(proc.returncode, proc.stdout, proc.stderr, figures)


def stored(script: Path) -> tuple[str, dict[str, Path]]:
    """The stored stdout and figures of ``script`` (what the site shows)."""
    folder = STORE / script.stem
    if not (folder / "output.txt").is_file():
        raise FileNotFoundError(f"{script.name}: no stored output in "
                                f"{folder.relative_to(REPO)} (make example-outputs)")
    text = (folder / "output.txt").read_text()
    figures = {p.relative_to(folder).as_posix(): p for p in sorted(folder.rglob("*.png"))}
    return text, figures


def store(script: Path) -> None:
    """Run ``script`` and replace its stored outputs with this run's (only after it ran)."""
    with tempfile.TemporaryDirectory() as tmp:
        result = run(script, Path(tmp))
        if result.returncode != 0:
            raise SystemExit(f"{script.name} exited {result.returncode}: "
                             f"{result.stderr.strip().splitlines()[-1:]}")
        folder = STORE / script.stem
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        (folder / "output.txt").write_text(result.stdout)
        for rel, path in result.figures.items():
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, folder / rel)
    print(f"stored {script.name}: {len(result.stdout.splitlines())} lines, "
          f"{len(result.figures)} figures in {folder.relative_to(REPO)}")


if __name__ == "__main__":
    names = sys.argv[1:]
    for path in scripts():
        if not names or path.name in names or path.stem in names:
            store(path)
