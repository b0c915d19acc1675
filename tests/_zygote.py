"""Child processes forked from one that has imported the project already: a ``subprocess.Popen`` for the tests
whose subject is what a command does once it runs (a signal in the middle of a phase, a docs page's code), not
how it starts.

A fresh ``python -c`` pays the imports again (one to two CPU seconds for the evaluator, three with torch), and the
suite starts dozens of them. The server here imports the modules it is given once, freezes them for the garbage
collector, and forks a child per request, as :mod:`multiprocessing.forkserver` does (whose one server per
process the evaluator uses for its own workers). The child is a process of its own: its own pid, signal
handlers, file descriptors 0-2 (the caller's pipes), working folder and environment; it runs the code as
``python -c`` would, and exits as that would, through the interpreter's normal exit (``SystemExit``'s code, an
uncaught ``KeyboardInterrupt`` ending it by SIGINT, atexit handlers run).

What a child does not get afresh: the modules the server preloaded, with whatever they read from the
environment when they were imported (the server starts with the test process's). Tests of a command's start-up
(its imports, its first second) and tests that change such variables run ``python`` themselves.
"""

from __future__ import annotations

import array
import os
import pickle
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

#: The server: ``python -c SERVER <socket fd> <code run after the imports> <module> ...``. The forked child
#: returns from ``_serve`` with its request and runs it as the ``-c`` program, in the namespace emptied first.
SERVER = r"""
import array, gc, importlib, io, os, pickle, select, signal, socket, sys

def _serve():
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C of the test run is the tests' to handle
    gc.disable()  # the imports build long-lived objects only: no full passes over them while they load
    for name in sys.argv[3:]:
        importlib.import_module(name)
    exec(sys.argv[2], {})
    gc.freeze()
    gc.enable()
    server = socket.socket(fileno=int(sys.argv[1]))
    server.sendall(b"ready\n")
    requests = {}  # child pid -> its request's status socket
    while True:
        readable, _, _ = select.select([server], [], [], 0.01)
        while requests:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                break
            reply = requests.pop(pid)
            try:
                reply.sendall(b"%d\n" % status)
            except OSError:  # the caller gave up waiting
                pass
            reply.close()
        if not readable:
            continue
        fds = array.array("i")
        message, ancillary, _, _ = server.recvmsg(1 << 20, socket.CMSG_SPACE(4 * fds.itemsize))
        if not message:  # the caller closed its end: it ended, and so does the server
            return None
        for level, kind, data in ancillary:
            if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
                fds.frombytes(data[: len(data) - len(data) % fds.itemsize])
        stdin, stdout, stderr, reply_fd = fds
        request = pickle.loads(message)
        pid = os.fork()
        if pid == 0:
            server.close()
            for reply in requests.values():
                reply.close()
            os.close(reply_fd)
            for target, fd in ((0, stdin), (1, stdout), (2, stderr)):
                os.dup2(fd, target)
            for fd in {stdin, stdout, stderr} - {0, 1, 2}:
                os.close(fd)
            return request
        for fd in (stdin, stdout, stderr):
            os.close(fd)
        reply = socket.socket(fileno=reply_fd)
        requests[pid] = reply
        reply.sendall(b"%d\n" % pid)

def _become(request):
    # What a fresh interpreter would have: the caller's folder, environment and arguments, default handlers
    # (Python's own for SIGINT), and standard streams on the caller's descriptors, unbuffered if asked.
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    for name in ("SIGTERM", "SIGHUP", "SIGQUIT", "SIGCHLD", "SIGUSR1", "SIGUSR2", "SIGALRM"):
        signal.signal(getattr(signal, name), signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.argv = ["-c", *request["args"]]
    sys.path[:0] = [entry for entry in os.environ.get("PYTHONPATH", "").split(os.pathsep) if entry]
    unbuffered = bool(os.environ.get("PYTHONUNBUFFERED"))
    sys.stdin = io.TextIOWrapper(io.BufferedReader(io.FileIO(0, "r", closefd=False)), encoding="utf-8")
    sys.stdout = io.TextIOWrapper(
        io.BufferedWriter(io.FileIO(1, "w", closefd=False)), encoding="utf-8", write_through=unbuffered
    )
    sys.stderr = io.TextIOWrapper(
        io.BufferedWriter(io.FileIO(2, "w", closefd=False)), encoding="utf-8", errors="backslashreplace",
        line_buffering=True, write_through=unbuffered,
    )
    sys.__stdin__, sys.__stdout__, sys.__stderr__ = sys.stdin, sys.stdout, sys.stderr
    code = compile(request["code"], "<string>", "exec")
    namespace = sys.modules["__main__"].__dict__
    fresh = ("__name__", "__builtins__", "__doc__", "__spec__", "__loader__", "__package__", "__annotations__")
    for key in [key for key in namespace if key not in fresh]:
        del namespace[key]
    return code, namespace

_request = _serve()
if _request is None:
    sys.exit(0)
exec(*_become(_request))
"""


class Zygote:
    """A server that has imported ``modules``, then run ``then``; :meth:`popen` forks a child of it to run a
    ``-c`` program."""

    def __init__(self, modules: Iterable[str], then: str = "", env: Mapping[str, str] | None = None) -> None:
        self._socket, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._server = subprocess.Popen(
            [sys.executable, "-c", SERVER, str(theirs.fileno()), then, *modules],
            pass_fds=(theirs.fileno(),),
            stdin=subprocess.DEVNULL,
            env=dict(os.environ if env is None else env),
        )
        theirs.close()
        self._ready = False

    def _wait_ready(self, timeout: float = 120.0) -> None:
        if self._ready:
            return
        self._socket.settimeout(timeout)
        try:
            line = self._socket.recv(16)
        finally:
            self._socket.settimeout(None)
        if line != b"ready\n":
            self.close()
            raise RuntimeError(f"the zygote did not start (exit code {self._server.poll()})")
        self._ready = True

    def popen(
        self,
        code: str,
        args: Sequence[str] = (),
        *,
        cwd: os.PathLike[str] | str | None = None,
        env: Mapping[str, str] | None = None,
        stdin: int | None = subprocess.DEVNULL,
        stdout: int | None = subprocess.PIPE,
        stderr: int | None = subprocess.PIPE,
    ) -> ZygoteProcess:
        """``python -c code *args``, forked from the server; ``stdin``/``stdout``/``stderr`` as
        ``subprocess.Popen`` takes them (``PIPE``, ``DEVNULL``, ``None`` for this process's own, or a file
        descriptor). The entries of ``env``'s ``PYTHONPATH`` go first on the child's ``sys.path``, as they would."""
        self._wait_ready()
        ours: dict[str, int] = {}
        theirs: list[int] = []
        closing: list[int] = []
        for name, target, spec in (("stdin", 0, stdin), ("stdout", 1, stdout), ("stderr", 2, stderr)):
            if spec == subprocess.PIPE:
                read, write = os.pipe()
                ours[name], theirs_fd = (write, read) if target == 0 else (read, write)
                closing.append(theirs_fd)
            elif spec == subprocess.DEVNULL:
                theirs_fd = os.open(os.devnull, os.O_RDWR)
                closing.append(theirs_fd)
            elif spec is None:
                theirs_fd = target
            elif spec == subprocess.STDOUT and target == 2:
                theirs_fd = theirs[1]
            else:
                theirs_fd = int(spec)
            theirs.append(theirs_fd)
        reply, reply_theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        request = {
            "code": code,
            "args": list(map(str, args)),
            "cwd": os.fspath(cwd) if cwd is not None else os.getcwd(),
            "env": dict(os.environ if env is None else env),
        }
        fds = array.array("i", [*theirs, reply_theirs.fileno()])
        self._socket.sendmsg([pickle.dumps(request)], [(socket.SOL_SOCKET, socket.SCM_RIGHTS, fds)])
        for fd in closing:
            os.close(fd)
        reply_theirs.close()
        return ZygoteProcess(["python", "-c", code, *map(str, args)], reply, ours)

    def close(self) -> None:
        self._socket.close()
        try:
            self._server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._server.kill()
            self._server.wait()


class ZygoteProcess:
    """The part of ``subprocess.Popen`` the tests use, for a child of a :class:`Zygote`: ``pid``, ``returncode``,
    ``stdin``/``stdout``/``stderr`` (text), ``poll``, ``wait``, ``communicate``, ``send_signal``, ``terminate``,
    ``kill``. The exit status comes from the server, which reaps the child."""

    def __init__(self, args: list[str], reply: socket.socket, pipes: dict[str, int]) -> None:
        self.args = args
        self._reply = reply
        self._buffer = b""
        self.pid = int(self._line(None))
        self.returncode: int | None = None
        self.stdin = open(pipes["stdin"], "w", encoding="utf-8") if "stdin" in pipes else None  # noqa: SIM115
        self.stdout = open(pipes["stdout"], encoding="utf-8") if "stdout" in pipes else None  # noqa: SIM115
        self.stderr = open(pipes["stderr"], encoding="utf-8") if "stderr" in pipes else None  # noqa: SIM115

    def _line(self, timeout: float | None) -> bytes | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while b"\n" not in self._buffer:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            if not select.select([self._reply], [], [], left)[0]:
                return None
            chunk = self._reply.recv(64)
            if not chunk:
                raise RuntimeError("the zygote ended before it reported its child's exit")
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line

    def _status(self, timeout: float | None) -> int | None:
        if self.returncode is None:
            line = self._line(timeout)
            if line is not None:
                self.returncode = os.waitstatus_to_exitcode(int(line))
                self._reply.close()
        return self.returncode

    def poll(self) -> int | None:
        return self._status(0.0)

    def wait(self, timeout: float | None = None) -> int:
        code = self._status(timeout)
        if code is None:
            raise subprocess.TimeoutExpired(self.args, timeout)  # type: ignore[arg-type]
        return code

    def communicate(self, input: str | None = None, timeout: float | None = None) -> tuple[str | None, str | None]:
        """Like ``Popen.communicate``: writes ``input``, reads both pipes to their end, waits for the exit."""
        deadline = None if timeout is None else time.monotonic() + timeout
        if self.stdin is not None and not self.stdin.closed:
            if input:
                self.stdin.write(input)
            self.stdin.close()
        pipes = [s for s in (self.stdout, self.stderr) if s is not None and not s.closed]
        read = {s.fileno(): s for s in pipes}
        chunks: dict[int, list[bytes]] = {fd: [] for fd in read}
        while read:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                raise subprocess.TimeoutExpired(self.args, timeout)  # type: ignore[arg-type]
            for fd in select.select(list(read), [], [], left)[0]:
                data = os.read(fd, 1 << 16)
                if data:
                    chunks[fd].append(data)
                else:
                    read.pop(fd).close()
        self.wait(None if deadline is None else max(0.0, deadline - time.monotonic()))
        texts = {id(s): b"".join(chunks[fd]).decode("utf-8") for fd, s in zip(chunks, pipes, strict=True)}
        return texts.get(id(self.stdout)), texts.get(id(self.stderr))

    def send_signal(self, signum: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, signum)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


def run(
    zygote: Zygote,
    code: str,
    args: Sequence[str] = (),
    *,
    input: str | None = None,
    timeout: float | None = None,
    **kwargs: Any,
) -> subprocess.CompletedProcess[str]:
    """``subprocess.run([python, "-c", code, *args], capture_output=True, text=True, ...)`` through ``zygote``."""
    process = zygote.popen(code, args, stdin=subprocess.PIPE if input is not None else subprocess.DEVNULL, **kwargs)
    try:
        out, err = process.communicate(input, timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        raise
    assert process.returncode is not None
    return subprocess.CompletedProcess(process.args, process.returncode, out, err)
