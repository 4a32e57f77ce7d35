"""Run by test_template_isolation.py the way the template child runs (``python -S -P``,
the child's import path and environment): applies the named layers of the child's
confinement (:func:`adclient.template_child.confine`), then tries what they are to stop,
and prints JSON: each try's outcome ("ok" or its errno's name), the uid, and what
``confine`` reported; then tries to run a program (``exec``: a line of its own).

argv: TMP (a folder anyone may write in, holding ``secret``: root's, mode 600), PORT (a
TCP port the test listens on), then the layers (none: the control, where all works).
"""

from __future__ import annotations

import errno
import json
import os
import signal
import socket
import sys
from collections.abc import Callable

from adclient.template_child import confine


def outcome(attempt: Callable[[], object]) -> str:
    try:
        attempt()
    except OSError as error:
        return errno.errorcode.get(error.errno or 0, str(error))
    return "ok"


def fork() -> None:
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)


def connect(port: int) -> None:
    with socket.socket() as client:  # (create_connection would import the idna codec)
        client.connect(("127.0.0.1", port))


def main() -> None:
    tmp, port, *layers = sys.argv[1:]
    opened = os.open(os.path.join(tmp, "opened"), os.O_WRONLY | os.O_CREAT, 0o600)
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past RLIMIT_FSIZE: EFBIG
    isolation = confine(1 << 30, 60, tmp, layers)
    tries: dict[str, Callable[[], object]] = {
        "read": lambda: open("/etc/passwd", "rb").close(),
        "read secret": lambda: open(os.path.join(tmp, "secret"), "rb").close(),
        "write": lambda: open(os.path.join(tmp, "written"), "wb").close(),
        "write opened": lambda: os.write(opened, b"x"),
        "mkdir": lambda: os.mkdir(os.path.join(tmp, "made")),
        "connect": lambda: connect(int(port)),
        "fork": fork,
        "signal": lambda: os.kill(os.getppid(), 0),
    }
    report = {name: outcome(attempt) for name, attempt in tries.items()}
    print(json.dumps({**report, "uid": os.getuid(), "isolation": isolation}), flush=True)
    program = [sys.executable, "-S", "-c", 'print(\'{"exec": "ok"}\')']
    print(json.dumps({"exec": outcome(lambda: os.execv(program[0], program))}))


if __name__ == "__main__":
    main()
