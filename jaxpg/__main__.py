"""`jaxpg` and `python -m jaxpg`: the command, Ctrl-C handled from its first moment.

The command's module (`jaxpg.cli`) imports much of Python's standard library before its `main`
can take Ctrl-C over. This entry point imports nothing that the interpreter has not loaded
already, so a Ctrl-C from the moment `import jaxpg` has run ends the command with status 130 and
one line, where Python would print a KeyboardInterrupt's traceback. Nothing has been written yet.
"""

import os
import signal
import types


def _interrupted_while_starting(signum: int, frame: types.FrameType | None) -> None:
    """Ctrl-C before the command's own handler is in place: ends the process at once."""
    os.write(2, b"jaxpg: interrupted\n")
    os._exit(130)


def main() -> None:
    """The installed `jaxpg` command (`jaxpg.cli.main`), after the early Ctrl-C handler."""
    signal.signal(signal.SIGINT, _interrupted_while_starting)
    from jaxpg import cli

    cli.main()


if __name__ == "__main__":
    main()
