"""`python -m climbsim ARGS…`: the installed binary, as `climbsim ARGS…`."""

from __future__ import annotations

import os
import subprocess
import sys

from ._binary import find_binary
from ._errors import ClimbsimError


def main() -> None:
    try:
        binary = find_binary()
    except ClimbsimError as error:
        print(f"climbsim: {error}", file=sys.stderr)
        sys.exit(2)
    if sys.platform == "win32":
        sys.exit(subprocess.call([binary, *sys.argv[1:]]))
    os.execv(binary, [binary, *sys.argv[1:]])


if __name__ == "__main__":
    main()
