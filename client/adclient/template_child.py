"""The process that expands a template: ``python -S -P template_child.py MEMORY SECONDS
TMP``, started by :func:`adclient.templates.expand_checked`; JSON ``{template, points}``
(and the checks: ``robots``, ``links``, ``max_bytes``, ``max_total_bytes``) on stdin,
lines of JSON on stdout.

Defence in depth behind the template language (:mod:`adclient.template_expr` runs no
code): were a template to run code all the same, it would run here, confined. The child
imports all it needs and expands a small template once (xacro and the evaluator import
some modules on first use), then confines itself (:func:`confine`), and only then reads
the request: no user's text is read before the confinement. It answers a line of JSON
for each point as it is done (``{point, urdf}`` or ``{point, error, stage}``), after
one of ``{isolation}``. Each layer is applied where this machine allows it and reported
where it does not (the caller logs it): see docs/security.md, "The template child".
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import resource
import sys
from collections.abc import Callable, Collection
from typing import Any

NOBODY = 65534
"""The uid and gid a child started as root runs as."""
OPEN_FILES = 3
"""The descriptors the child may have: stdin, stdout and stderr, already open; it can
open no file, socket or pipe."""
LAYERS = ("limits", "network", "root", "user", "landlock")
NICE = 19
"""The child's CPU priority (``limits``): the lowest."""

_CLONE_NEWUSER = 0x10000000
_CLONE_NEWNET = 0x40000000
_PR_SET_DUMPABLE = 4
_PR_SET_NO_NEW_PRIVS = 38
_LANDLOCK_CREATE_RULESET, _LANDLOCK_RESTRICT_SELF = 444, 446  # one number on every arch
_LANDLOCK_CREATE_RULESET_VERSION = 1
_LANDLOCK_FS_RIGHTS = {1: 13, 2: 14, 3: 15, 4: 15}
"""How many filesystem rights (the low bits) each Landlock ABI knows; 16 from ABI 5."""
_LANDLOCK_NET_TCP = 0b11  # bind and connect (ABI 4)
_LANDLOCK_SCOPES = 0b11  # abstract Unix sockets and signals outside the domain (ABI 6)


class _LandlockRuleset(ctypes.Structure):
    _fields_ = [
        ("handled_access_fs", ctypes.c_uint64),
        ("handled_access_net", ctypes.c_uint64),
        ("scoped", ctypes.c_uint64),
    ]


class _CapHeader(ctypes.Structure):
    _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]


class _CapData(ctypes.Structure):
    _fields_ = [
        ("effective", ctypes.c_uint32),
        ("permitted", ctypes.c_uint32),
        ("inheritable", ctypes.c_uint32),
    ]


def confine(
    memory: int, seconds: int, tmp: str, layers: Collection[str] = LAYERS
) -> dict[str, dict[str, str]]:
    """Confines this process for good: ``{"applied": {layer: what}, "missing": {layer:
    why not}}``. ``limits`` (rlimits) always apply; the others only where the kernel and
    this process's privileges allow (``tmp``: where the empty root is made and at once
    removed). ``layers`` picks some, to show what each one stops alone."""
    report: dict[str, dict[str, str]] = {"applied": {}, "missing": {}}

    def attempt(layer: str, step: Callable[[], str]) -> bool:
        if layer not in layers:
            return False
        try:
            report["applied"][layer] = step()
        except (OSError, AttributeError) as error:  # AttributeError: libc lacks the call
            report["missing"][layer] = _reason(error)
            return False
        report["missing"].pop(layer, None)
        return True

    if "limits" in layers:
        # the lowest CPU priority: an expansion never takes a core from the requests
        # and workers beside it, however long it runs
        os.nice(NICE - os.nice(0))
        _limit(resource.RLIMIT_AS, memory)
        # the soft limit sends SIGXCPU, which ends the child with its own exit status; a
        # hard limit equal to it would send SIGKILL instead, read as an unexplained failure
        _limit(resource.RLIMIT_CPU, seconds, seconds + 1)
        # SIGXCPU and an abort dump core: never a file of up to the memory limit
        _limit(resource.RLIMIT_CORE, 0)
    root = os.geteuid() == 0
    if root:  # root's steps, then root is given up
        if attempt("network", lambda: _unshare(_CLONE_NEWNET, "a network namespace")) or (
            "network" not in layers
        ):
            attempt("root", lambda: _empty_root(tmp))
        attempt("user", _become_nobody)
    # without CAP_SYS_ADMIN, as nobody or the user: a user namespace of its own, whose
    # capabilities (given up after) make the chroot; a chrooted process could make none
    if "network" not in report["applied"] and attempt(
        "network",
        lambda: _unshare(
            _CLONE_NEWUSER | _CLONE_NEWNET, "a user namespace and a network namespace"
        ),
    ):
        if "root" not in report["applied"]:
            attempt("root", lambda: _empty_root(tmp))
        _drop_capabilities()
    if not root:
        attempt("user", _drop_capabilities)
    if attempt("landlock", _landlock):
        report["missing"].update(_landlock_gaps(_landlock_abi()))
    if "limits" in layers:
        _limit(resource.RLIMIT_FSIZE, 0)  # a regular file written: SIGXFSZ
        _limit(resource.RLIMIT_NOFILE, OPEN_FILES)
        _limit(resource.RLIMIT_NPROC, 0)  # after the uid drop: root's is not enforced
        report["applied"]["limits"] = (
            f"{memory} bytes, {seconds} s of CPU at nice {NICE}, no core, no file written, "
            f"{OPEN_FILES} descriptors, no new process"
        )
    if "root" in layers and "root" not in report["applied"]:
        network = report["missing"].get("network", "not asked for")
        report["missing"].setdefault("root", f"needs root, or a user namespace ({network})")
    return report


def _limit(which: int, soft: int, hard: int | None = None) -> None:
    """Lowers a limit (never above the hard limit this process was given)."""
    _, given = resource.getrlimit(which)
    hard = soft if hard is None else hard
    if given != resource.RLIM_INFINITY:
        soft, hard = min(soft, given), min(hard, given)
    resource.setrlimit(which, (soft, hard))


def _reason(error: BaseException) -> str:
    if isinstance(error, OSError) and error.errno is not None:
        return f"{errno.errorcode.get(error.errno, error.errno)}: {error.strerror}"
    return str(error)


def _libc() -> Any:
    return ctypes.CDLL(None, use_errno=True)


def _check(result: int) -> int:
    if result == -1:
        number = ctypes.get_errno()
        raise OSError(number, os.strerror(number))
    return result


def _unshare(flags: int, what: str) -> str:
    """New, empty namespaces: a network one has only a loopback that is down, so no
    address (the server's included) can be reached."""
    _check(_libc().unshare(ctypes.c_int(flags)))
    return what


def _empty_root(tmp: str) -> str:
    """chroot into an empty folder that is removed first: nothing under it, and nothing
    can be made in a removed folder; none is left behind."""
    folder = os.path.join(tmp, f"adclient-template-root-{os.getpid()}-{os.urandom(6).hex()}")
    os.mkdir(folder, 0o500)
    os.chdir(folder)
    os.rmdir(folder)
    os.chroot(".")
    return "an empty, removed folder"


def _become_nobody() -> str:
    """Root's uid, gid and groups given up for nobody's (and with them every capability);
    not dumpable, so no other process of nobody can trace it. Where nobody is not to be
    had (root of a user namespace that maps one uid), root's capabilities are dropped."""
    try:
        os.setgroups([])
        os.setgid(NOBODY)
        os.setuid(NOBODY)
    except OSError as error:
        _drop_capabilities()
        message = f"cannot become nobody ({error.strerror}): uid 0 without capabilities"
        raise OSError(error.errno, message) from None
    _check(_libc().prctl(_PR_SET_DUMPABLE, ctypes.c_ulong(0), 0, 0, 0))
    return f"uid and gid {NOBODY}, no groups, no capabilities"


def _drop_capabilities() -> str:
    """An unprivileged process's capabilities (those of its own user namespace) given up."""
    header = _CapHeader(0x20080522, 0)  # _LINUX_CAPABILITY_VERSION_3
    _check(_libc().capset(ctypes.byref(header), (_CapData * 2)()))
    _check(_libc().prctl(_PR_SET_DUMPABLE, ctypes.c_ulong(0), 0, 0, 0))
    return f"uid {os.getuid()}, no capabilities"


def _landlock_abi() -> int:
    """The kernel's Landlock ABI version; OSError (ENOSYS, EOPNOTSUPP) without it."""
    if not sys.platform.startswith("linux"):
        raise OSError(errno.ENOSYS, "Landlock is Linux's")
    return _check(
        _libc().syscall(
            ctypes.c_long(_LANDLOCK_CREATE_RULESET),
            None,
            ctypes.c_size_t(0),
            ctypes.c_uint32(_LANDLOCK_CREATE_RULESET_VERSION),
        )
    )


def _landlock_gaps(abi: int) -> dict[str, str]:
    """What an older Landlock leaves to the other layers."""
    gaps = {}
    if abi < 4:
        gaps["landlock network"] = f"Landlock ABI {abi} has no TCP rules (from ABI 4)"
    if abi < 6:
        gaps["landlock scopes"] = f"Landlock ABI {abi} has no signal and socket scopes (from 6)"
    return gaps


def _landlock() -> str:
    """A Landlock domain that handles every right it knows and allows none: no file
    opened, made, removed or run, no TCP bind or connect, no signal or abstract socket
    outside it. Needs no_new_privs, which also keeps any exec from gaining privileges."""
    libc = _libc()
    abi = _landlock_abi()
    ruleset = _LandlockRuleset(
        handled_access_fs=(1 << _LANDLOCK_FS_RIGHTS.get(abi, 16)) - 1,
        handled_access_net=_LANDLOCK_NET_TCP if abi >= 4 else 0,
        scoped=_LANDLOCK_SCOPES if abi >= 6 else 0,
    )
    descriptor = _check(
        libc.syscall(
            ctypes.c_long(_LANDLOCK_CREATE_RULESET),
            ctypes.byref(ruleset),
            ctypes.c_size_t(ctypes.sizeof(ruleset)),
            ctypes.c_uint32(0),
        )
    )
    try:
        _check(libc.prctl(_PR_SET_NO_NEW_PRIVS, ctypes.c_ulong(1), 0, 0, 0))
        _check(
            libc.syscall(
                ctypes.c_long(_LANDLOCK_RESTRICT_SELF), ctypes.c_int(descriptor), ctypes.c_uint32(0)
            )
        )
    finally:
        os.close(descriptor)
    return f"ABI {abi}: no file, no TCP, no signal or abstract socket outside"


def main() -> None:
    memory, seconds = (int(value) for value in sys.argv[1:3])
    from adclient.templates import TemplateError, expand
    from adclient.urdf_model import URDFModelError, read_urdf

    # what xacro, the evaluator and the URDF reader import on first use, imported now (a
    # valid and a failing expansion, a robot read): once confined, the child opens no module
    expand('<robot name="r"><link name="${n * 2}_$(arg n)"/></robot>', {"n": 1})
    with contextlib.suppress(TemplateError):
        expand('<robot name="r"><link name="${m}"/></robot>', {})
    with contextlib.suppress(URDFModelError):
        read_urdf('<robot name="r"><link name="a"/></robot>', lines_from="<r/>")
    isolation = confine(memory, seconds, sys.argv[3])
    request = json.loads(sys.stdin.buffer.read())
    _answer({"isolation": isolation})
    expansions = _Expansions(request)
    for index, point in enumerate(request["points"]):
        try:
            answer = expansions.checked(point)
        except TemplateError as error:
            answer = {"error": str(error)}
        except MemoryError:
            answer = {"error": f"template: expanding it needs over {memory} bytes"}
        except Exception as error:  # a point's own failure: the next points still expand
            answer = {"error": f"template: {type(error).__name__}: {str(error)[:200]}"}
        _answer({"point": index, **answer})


def _answer(line: dict[str, Any]) -> None:
    """One line of the answer, written at once: a child stopped at its limit has told
    the points it finished."""
    sys.stdout.write(json.dumps(line) + "\n")
    sys.stdout.flush()


class _Expansions:
    """The request's points expanded and checked one by one (``templates.expand_checked``):
    each URDF within its byte limit and all of them within the total's, and, where the
    request asks, a robot the worker can build having the links the task looks up."""

    def __init__(self, request: dict[str, Any]) -> None:
        from adclient.templates import MAX_URDF_BYTES

        self.template: str = request["template"]
        self.robots = bool(request.get("robots", False))
        self.links: list[list[str]] = request.get("links") or []
        self.max_bytes, self.max_named = request.get("max_bytes") or [
            MAX_URDF_BYTES,
            f"the limit of {MAX_URDF_BYTES:,} bytes",
        ]
        total = request.get("max_total_bytes")
        self.max_total: int | None = total[0] if total else None
        self.total_named: str = total[1] if total else ""
        self.total = 0

    def checked(self, point: dict[str, Any]) -> dict[str, Any]:
        from adclient.templates import expand
        from adclient.urdf_model import URDFModelError, read_urdf

        urdf = expand(self.template, point)
        size = len(urdf.encode())
        if size > self.max_bytes:
            return _refused(f"it is {size:,} bytes, over {self.max_named}")
        if self.max_total is not None and self.total + size > self.max_total:
            return _refused(
                f"it is {size:,} bytes, and with the {self.total:,} of those before it, "
                f"over {self.total_named}"
            )
        if self.robots:
            try:
                model = read_urdf(urdf, lines_from=self.template)
            except URDFModelError as error:
                return _refused(str(error))
            for option, link in self.links:
                if link not in model.links:
                    return {
                        "error": f"task.options.{option}: the template's robot has no link "
                        f"{link!r} (its links: {', '.join(list(model.links)[:20])})",
                        "stage": "links",
                    }
        self.total += size
        return {"urdf": urdf}


def _refused(problem: str) -> dict[str, str]:
    return {"error": problem, "stage": "robot"}


if __name__ == "__main__":
    main()
