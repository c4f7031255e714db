"""Where the `climbsim` binary is: the wheel puts it in the environment's scripts folder."""

from __future__ import annotations

import os
import shutil
import sys
import sysconfig
from pathlib import Path

from ._errors import ClimbsimError

_NAME = "climbsim.exe" if sys.platform == "win32" else "climbsim"


def _candidates() -> list[Path]:
    # The environment this package is installed in (a venv, the system), then a `pip install
    # --user`, then `pip install --target DIR` (the package in DIR, the binary in DIR/bin).
    folders = [sysconfig.get_path("scripts")]
    user_scheme = f"{os.name}_user"
    if user_scheme in sysconfig.get_scheme_names():
        folders.append(sysconfig.get_path("scripts", scheme=user_scheme))
    folders.append(str(Path(__file__).resolve().parent.parent / "bin"))
    return [Path(folder) / _NAME for folder in folders if folder]


def find_binary() -> str:
    """The `climbsim` binary: `$CLIMBSIM_BINARY` if set, else the one this package was
    installed with, else the first on PATH."""
    given = os.environ.get("CLIMBSIM_BINARY")
    if given:
        if not os.access(given, os.X_OK):
            raise ClimbsimError(f"CLIMBSIM_BINARY={given} is not an executable file")
        return given
    for candidate in _candidates():
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    on_path = shutil.which(_NAME)
    if on_path:
        return on_path
    raise ClimbsimError(
        "the climbsim binary was not found beside this package nor on PATH: "
        "reinstall the wheel (pip install climbsim), or set CLIMBSIM_BINARY to the binary"
    )
