"""The channel between the grader (trusted) and the student's process (untrusted): framed
messages over two pipes, and the checks the trusted side applies to every answer.

A frame is a 5-byte header (body length, little-endian uint32; kind, one byte) and a body:
``KIND_JSON`` (a UTF-8 JSON object) or ``KIND_ARRAY`` (little-endian float64 values, the
per-tick answers). The trusted side reads with a deadline and a size cap
(:data:`MAX_FRAME_BYTES`), and every value it takes from an answer goes through
:func:`as_array` / :func:`as_text` (shape, dtype, finiteness, length). Anything else (a
frame too long, bytes that do not parse, a missing field) is a :class:`ProtocolError`: the
student's process broke the channel, and its test fails.
"""

from __future__ import annotations

import errno
import json
import math
import os
import select
import struct
import time

import numpy as np

HEADER = struct.Struct("<IB")
KIND_JSON = 1
KIND_ARRAY = 2
MAX_FRAME_BYTES = 4 << 20
"""Largest answer the trusted side reads [bytes] (a joint trajectory of up to
:data:`MAX_SEGMENTS` segments fits)."""
MAX_TEXT_CHARS = 2000
"""Longest text (an error message, a traceback) taken from the student's process."""
MAX_SEGMENTS = 1000
"""Most segments of a trajectory taken from the student's process."""
MAX_DEGREE = 9
"""Highest polynomial degree of a trajectory's segment taken from the student's process."""


class ProtocolError(Exception):
    """The other side sent something that is not a valid answer (the message says what)."""


class ChannelClosed(ProtocolError):
    """The other side closed its end (its process ended, or closed the descriptor)."""


class ChannelTimeout(ProtocolError):
    """No (complete) answer before the deadline."""


class Channel:
    """One end of the channel: reads ``rfd``, writes ``wfd`` (both pipes)."""

    def __init__(self, rfd: int, wfd: int, *, max_frame: int = MAX_FRAME_BYTES):
        self.rfd, self.wfd = rfd, wfd
        self.max_frame = max_frame
        self._pollers = {}
        for fd, event in ((rfd, select.POLLIN), (wfd, select.POLLOUT)):
            poller = select.poll()
            poller.register(fd, event | select.POLLHUP | select.POLLERR)
            self._pollers[fd] = poller

    # Writing ----------------------------------------------------------------------------

    def _send(self, kind: int, body: bytes, deadline: float | None) -> None:
        data = memoryview(HEADER.pack(len(body), kind) + body)
        while data:
            try:
                n = os.write(self.wfd, data)
            except BlockingIOError:
                self._wait(self.wfd, deadline, "to take the grader's request")
                continue
            except BrokenPipeError:
                raise ChannelClosed("the process closed the channel") from None
            data = data[n:]

    def send_json(
        self, obj: dict, deadline: float | None = None, *, allow_nan: bool = False
    ) -> None:
        """Sends a JSON object (``allow_nan``: NaN and infinities as JSON's extensions)."""
        self._send(KIND_JSON, json.dumps(obj, allow_nan=allow_nan).encode(), deadline)

    def send_array(self, values: np.ndarray, deadline: float | None = None) -> None:
        """Sends float64 values."""
        self._send(KIND_ARRAY, np.asarray(values, dtype="<f8").tobytes(), deadline)

    # Reading ----------------------------------------------------------------------------

    def _wait(self, fd: int, deadline, what: str) -> None:
        # A deadline: a time.monotonic() time, or a test's clock (doorlab.pset.rules.clock.Clock:
        # anything with remaining(), which counts what the test had, not the wall time). A poll
        # waits in wall time: where the process waited for a CPU meanwhile, the clock has time
        # left when it returns, so the wait goes on until the deadline's own count is spent.
        while True:
            if deadline is None:
                timeout = None
            elif hasattr(deadline, "remaining"):
                timeout = deadline.remaining()
            else:
                timeout = deadline - time.monotonic()
            if timeout is not None and timeout <= 0:
                raise ChannelTimeout(f"no answer in time (waiting {what})")
            ms = None if timeout is None else max(1, math.ceil(timeout * 1e3))
            if self._pollers[fd].poll(ms):
                return

    def _read_exactly(self, n: int, deadline: float | None) -> bytes:
        chunks, got = [], 0
        while got < n:
            self._wait(self.rfd, deadline, "for an answer")
            try:
                chunk = os.read(self.rfd, min(n - got, 1 << 20))
            except OSError as e:
                if e.errno in (errno.EAGAIN, errno.EINTR):
                    continue
                raise ChannelClosed(f"the channel failed: {e.strerror}") from None
            if not chunk:
                raise ChannelClosed("the process closed the channel")
            chunks.append(chunk)
            got += len(chunk)
        return b"".join(chunks)

    def receive(self, deadline: float | None = None) -> tuple[int, bytes]:
        """The next frame (kind, body)."""
        length, kind = HEADER.unpack(self._read_exactly(HEADER.size, deadline))
        if kind not in (KIND_JSON, KIND_ARRAY):
            raise ProtocolError(f"a frame of unknown kind {kind} (garbage on the channel)")
        if length > self.max_frame:
            raise ProtocolError(
                f"an answer of {length} bytes (the limit is {self.max_frame}; garbage on the "
                "channel?)"
            )
        return kind, self._read_exactly(length, deadline)

    def receive_json(self, deadline: float | None = None) -> dict:
        """The next frame, which must be a JSON object."""
        kind, body = self.receive(deadline)
        if kind != KIND_JSON:
            raise ProtocolError("an array where an object was expected")
        return parse_json(body)


def parse_json(body: bytes) -> dict:
    """A JSON object from untrusted bytes (ProtocolError if it is not one)."""
    try:
        value = json.loads(body.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise ProtocolError(f"an answer that is not JSON ({type(e).__name__})") from None
    if not isinstance(value, dict):
        raise ProtocolError(f"a JSON {type(value).__name__} where an object was expected")
    return value


def parse_array(body: bytes, size: int) -> np.ndarray:
    """``size`` float64 values from an array frame's body."""
    if len(body) != 8 * size:
        raise ProtocolError(f"{len(body)} bytes where {size} float64 values were expected")
    return np.frombuffer(body, dtype="<f8").astype(float)


def as_text(value, limit: int = MAX_TEXT_CHARS) -> str:
    """A string from an answer, cut to ``limit`` characters (non-strings become '')."""
    if not isinstance(value, str):
        return ""
    if len(value) > limit:
        return value[:limit] + f" [... {len(value) - limit} characters left out]"
    return value


def as_array(value, shape: tuple[int, ...], what: str, *, finite: bool = True) -> np.ndarray:
    """A float64 array of exactly ``shape`` from an answer's (nested) list.

    Raises:
        ProtocolError: Not numbers, another shape, or (``finite``) a NaN or an infinity;
            the message names ``what``.
    """
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError, RecursionError):
        raise ProtocolError(f"{what}: not an array of numbers") from None
    if array.shape != shape:
        raise ProtocolError(f"{what}: shape {array.shape}, expected {shape}")
    if finite and not np.all(np.isfinite(array)):
        raise ProtocolError(f"{what}: a non-finite value in {array.tolist()}")
    return array


def as_number(value, what: str) -> float:
    """A finite float from an answer."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(f"{what}: not a number")
    x = float(value)
    if not math.isfinite(x):
        raise ProtocolError(f"{what}: not finite ({x})")
    return x
