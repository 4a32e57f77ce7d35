"""The template child's confinement (issue 36), each claim of docs/security.md tried for
real: a probe process applies the layers one at a time, then all, and tries what each
is to stop (read /etc/passwd, write a file, connect to this test's port, fork, run a
program, signal this test); the real child is inspected from outside while it waits for
its template; and a layer the machine lacks is reported, logged once, and no expansion
fails for it."""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from adclient import templates
from adclient.template_child import LAYERS, NOBODY, OPEN_FILES

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="the template child's confinement is Linux's"
)
AS_ROOT = pytest.mark.skipif(
    os.geteuid() != 0,
    reason="NOT ROOT: the layers one by one, the uid drop and the child's /proc are not "
    "tested (CI runs as root)",
)
SETPRIV = shutil.which("setpriv")
NEEDS_SETPRIV = pytest.mark.skipif(
    SETPRIV is None,
    reason="setpriv (util-linux) not installed: a root without capabilities is not tested",
)
PROBE = Path(__file__).with_name("confinement_probe.py")
TRIES = ("read", "read secret", "write", "write opened", "mkdir", "connect", "fork", "signal")
TEMPLATE = '<robot name="r"><link name="a_${n * 2}"/></robot>'

STOPS: dict[str, dict[str, Any]] = {
    "limits": {
        "read": "EMFILE",
        "read secret": "EMFILE",
        "write": "EMFILE",
        "write opened": "EFBIG",
        "connect": "EMFILE",
    },
    "network": {"connect": "ENETUNREACH"},
    "root": {
        "read": "ENOENT",
        "read secret": "ENOENT",
        "write": "ENOENT",
        "mkdir": "ENOENT",
        "exec": "ENOENT",
    },
    "user": {"read secret": "EACCES", "signal": "EPERM", "uid": NOBODY},
    "landlock": {
        "read": "EACCES",
        "read secret": "EACCES",
        "write": "EACCES",
        "mkdir": "EACCES",
        "connect": "EACCES",
        "signal": "EPERM",
        "exec": "EACCES",
    },
}
"""What each layer stops on its own (as root): the errno each try meets."""


@pytest.fixture
def shared() -> Iterator[Path]:
    """A folder anyone may write in (nobody included), with a file only root may read."""
    folder = Path(tempfile.mkdtemp(prefix="template-isolation-"))
    try:
        folder.chmod(0o777)
        secret = folder / "secret"
        secret.write_text("root's only")
        secret.chmod(0o600)
        yield folder
    finally:
        shutil.rmtree(folder)


@pytest.fixture
def listener() -> Iterator[socket.socket]:
    """A TCP port of this process, standing in for the server's."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        server.setblocking(False)
        yield server


def connected(server: socket.socket) -> bool:
    try:
        connection, _ = server.accept()
    except BlockingIOError:
        return False
    connection.close()
    return True


def probe(shared: Path, listener: socket.socket, *layers: str) -> dict[str, Any]:
    command, env = templates.child_command()
    port = str(listener.getsockname()[1])
    done = subprocess.run(
        [command[0], "-S", "-P", str(PROBE), str(shared), port, *layers],
        env=env,
        capture_output=True,
        timeout=120,
        check=False,
    )
    outcome: dict[str, Any] = {}
    for line in done.stdout.decode().splitlines():
        outcome.update(json.loads(line))
    assert "isolation" in outcome, done.stderr.decode(errors="replace")[-500:]
    return outcome


@AS_ROOT
def test_unconfined_the_probe_does_all_it_tries(shared: Path, listener: socket.socket) -> None:
    """The control: with no layer every try works, so each refusal below is a layer's."""
    outcome = probe(shared, listener)
    assert {name: outcome[name] for name in (*TRIES, "exec")} == dict.fromkeys(
        (*TRIES, "exec"), "ok"
    )
    assert outcome["uid"] == 0
    assert connected(listener)


@AS_ROOT
@pytest.mark.parametrize("layer", LAYERS)
def test_each_layer_alone_stops_what_it_claims(
    shared: Path, listener: socket.socket, layer: str
) -> None:
    outcome = probe(shared, listener, layer)
    missing = outcome["isolation"]["missing"]
    if layer in missing:
        pytest.skip(f"{layer.upper()} UNAVAILABLE on this machine, not tested: {missing[layer]}")
    assert {name: outcome.get(name) for name in STOPS[layer]} == STOPS[layer]
    assert connected(listener) == ("connect" not in STOPS[layer])


@AS_ROOT
def test_all_layers_together_stop_every_try(shared: Path, listener: socket.socket) -> None:
    """What the child runs: nothing it tries works, it runs as nobody, and nothing
    reached the listening port or was written in the shared folder."""
    outcome = probe(shared, listener, *LAYERS)
    assert outcome["isolation"]["missing"] == {}, "a layer is missing on this machine"
    assert [name for name in (*TRIES, "exec") if outcome[name] == "ok"] == []
    assert outcome["fork"] == "EAGAIN"  # RLIMIT_NPROC 0, enforced once root is given up
    assert outcome["uid"] == NOBODY
    assert not connected(listener)
    assert sorted(path.name for path in shared.iterdir()) == ["opened", "secret"]
    assert (shared / "opened").read_bytes() == b""


def limits(pid: int) -> dict[str, tuple[str, str]]:
    text = Path(f"/proc/{pid}/limits").read_text()
    return {
        match[1]: (match[2], match[3])
        for match in re.finditer(r"^(Max [\w ]+?)\s{2,}(\S+)\s+(\S+)", text, re.M)
    }


def status(pid: int) -> dict[str, str]:
    lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    return dict((name, value.strip()) for name, _, value in (line.partition(":") for line in lines))


@AS_ROOT
@pytest.mark.parametrize(
    ("prefix", "namespaces"),
    [
        pytest.param([], "a network namespace", id="root"),
        pytest.param(
            [SETPRIV, "--bounding-set=-sys_admin", "--inh-caps=-sys_admin", "--"],
            "a user namespace and a network namespace",
            id="root without CAP_SYS_ADMIN",
            marks=NEEDS_SETPRIV,
        ),
    ],
)
def test_the_real_child_is_confined_before_it_reads_a_template(
    prefix: list[str], namespaces: str
) -> None:
    """The child started by child_command, seen from outside while it waits for its
    request: nobody, no capabilities, another network namespace, an empty root, its
    limits; then it expands the template all the same. Without CAP_SYS_ADMIN (a
    container) its namespaces are a user namespace's."""
    command, env = templates.child_command()
    child = subprocess.Popen(
        [*prefix, *command],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    assert child.stdin is not None
    try:
        # it confines itself before it reads: once it has taken in most of a megabyte
        # (more than a pipe holds), it is confined, and waits for the rest
        child.stdin.write(b" " * (1 << 20))
        child.stdin.flush()
        seen = status(child.pid)
        assert seen["Uid"].split() == [str(NOBODY)] * 4
        assert seen["Gid"].split() == [str(NOBODY)] * 4
        assert seen["Groups"] == ""
        assert int(seen["CapEff"], 16) == int(seen["CapPrm"], 16) == 0
        assert seen["NoNewPrivs"] == "1"
        assert os.readlink(f"/proc/{child.pid}/ns/net") != os.readlink("/proc/self/ns/net")
        assert os.listdir(f"/proc/{child.pid}/root") == []
        assert limits(child.pid) == {
            **limits(child.pid),
            "Max open files": (str(OPEN_FILES), str(OPEN_FILES)),
            "Max processes": ("0", "0"),
            "Max file size": ("0", "0"),
            "Max core file size": ("0", "0"),
            "Max cpu time": (str(templates.EXPAND_SECONDS), str(templates.EXPAND_SECONDS + 1)),
            "Max address space": (str(templates.EXPAND_MEMORY),) * 2,
        }
    finally:
        request = json.dumps({"template": TEMPLATE, "points": [{"n": 2}]}).encode()
        out, err = child.communicate(request, timeout=120)
    isolation, answer = (json.loads(line) for line in out.splitlines())  # a line a point
    assert answer == {"point": 0, "urdf": templates.expand(TEMPLATE, {"n": 2})}, err.decode()
    assert isolation["isolation"]["missing"] == {}
    assert isolation["isolation"]["applied"]["network"] == namespaces


@AS_ROOT
@NEEDS_SETPRIV
def test_a_layer_the_machine_lacks_is_logged_once_and_no_expansion_fails_for_it() -> None:
    """Root without CAP_SETUID (a container that drops it) cannot become nobody: each
    child says so in its answer and expands all the same, and its caller logs one
    warning naming the layer and why, however many templates it expands."""
    caller = (
        "import logging, sys\n"
        "from adclient.templates import expand_isolated\n"
        "logging.basicConfig(stream=sys.stderr, format='%(levelname)s %(message)s')\n"
        f"for n in (1, 2): print(expand_isolated({TEMPLATE!r}, [{{'n': n}}])[0])\n"
    )
    no_setuid = ["--bounding-set=-setuid,-setgid", "--inh-caps=-setuid,-setgid", "--"]
    done = subprocess.run(
        [SETPRIV or "", *no_setuid, sys.executable, "-c", caller],
        capture_output=True,
        timeout=120,
        check=True,
    )
    assert done.stdout.decode().count('<link name="a_') == 2
    assert 'name="a_4"' in done.stdout.decode()
    warnings = [line for line in done.stderr.decode().splitlines() if "runs without" in line]
    assert len(warnings) == 1, done.stderr.decode()
    assert warnings[0].startswith("WARNING the template-expanding child runs without user: ")
    assert "cannot become nobody" in warnings[0]
