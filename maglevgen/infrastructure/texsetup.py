"""TeX for report.pdf: the packages, and `make run`'s step that installs them where it can.

On a fresh Debian/Ubuntu machine `make run` installs the packages below with apt-get when it
may (as root, or through sudo without a password); otherwise it says in one line what to
install, and the build goes on without the PDF (its summary says so). Imports nothing heavy:
`make run` calls it before the first build.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

__all__ = ["INSTALL_HINT", "ensure_tex", "find_tex"]

# Debian packages the PDF needs (the README's "Report" section and .ci/run name the same list;
# poppler-utils gives pdftotext, with which the tests read the PDF back).
TEX_PACKAGES: tuple[str, ...] = (
    "latexmk",
    "texlive-latex-base",
    "texlive-latex-recommended",
    "texlive-fonts-recommended",
    "poppler-utils",
)
INSTALL_HINT = "apt-get install --no-install-recommends " + " ".join(TEX_PACKAGES)


def find_tex() -> str | None:
    """latexmk if installed, else pdflatex, else None."""
    for tool in ("latexmk", "pdflatex"):
        if shutil.which(tool):
            return tool
    return None


def _say(message: str) -> None:
    print(f"maglevgen: {message}", file=sys.stderr, flush=True)


def _passwordless_sudo() -> bool:
    if shutil.which("sudo") is None:
        return False
    try:
        return subprocess.run(["sudo", "-n", "true"], stdin=subprocess.DEVNULL,
                              capture_output=True, timeout=30, check=False).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def ensure_tex(euid: int | None = None) -> bool:
    """Install TeX with apt-get when it is missing and this user may; True when TeX is there
    afterwards. Every outcome other than "already installed" is one line on stderr."""
    if find_tex() is not None:
        return True
    if shutil.which("apt-get") is None:
        _say(f"TeX not found and no apt-get: report.pdf needs TeX Live with latexmk (on "
             f"Debian/Ubuntu: {INSTALL_HINT}); building without it")
        return False
    euid = os.geteuid() if euid is None else euid
    if euid == 0:
        prefix: list[str] = []
    elif _passwordless_sudo():
        prefix = ["sudo", "-n"]
    else:
        _say(f"TeX not found: for report.pdf run `sudo {INSTALL_HINT}`, then `make run` "
             "again; building without it")
        return False
    _say(f"TeX not found: installing it for report.pdf ({' '.join([*prefix, INSTALL_HINT])})")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for args in (["apt-get", "update", "-qq"],
                 ["apt-get", "install", "-y", "-qq", "--no-install-recommends", *TEX_PACKAGES]):
        try:
            proc = subprocess.run([*prefix, *args], env=env, stdin=subprocess.DEVNULL,
                                  capture_output=True, text=True, check=False)
            failure = f"exit code {proc.returncode}" if proc.returncode else ""
        except OSError as exc:
            failure = exc.strerror or str(exc)
        if failure:
            _say(f"could not install TeX (`{' '.join(args[:2])}`: {failure}); for report.pdf "
                 f"run `sudo {INSTALL_HINT}`; building without it")
            return False
    if find_tex() is None:
        _say("apt-get installed the TeX packages but neither latexmk nor pdflatex is on PATH; "
             "building without report.pdf")
        return False
    return True


if __name__ == "__main__":
    ensure_tex()  # never fails `make run`: the build says whether it made the PDF
