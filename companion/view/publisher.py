"""The view's sink: after each tick, the loop's state to an MCAP file and a Foxglove WebSocket server.

:class:`ViewPublisher` is called once per tick by whatever pumps the loop (lockstep harness,
replay, real-time stream) with the companion, the tick's link time and its outbox. It takes a
:class:`~companion.view.snapshot.TickSnapshot` there (copies only) and hands it on:

- *inline* (lockstep, replay: no wall clock to keep): the Foxglove messages are built and
  logged at once, so a recording holds every tick and every replan;
- *threaded* (``companion fly``): the snapshot goes into a bounded queue and a thread of this
  publisher builds and logs the messages. The queue drops its oldest snapshot when full
  (counted: ``view_dropped``); the tick never waits for the view. The Foxglove SDK's server
  runs on its own threads; it drops the oldest message of a slow client itself.

Both write through one Foxglove SDK context, so the file and the live view carry the same
channels (:mod:`companion.view.channels`). The SDK is the ``view`` extra; without it
:func:`open_view` raises :class:`~companion.offline.ulog.MissingExtra`-like
:class:`ViewUnavailable` naming the extra.
"""

from __future__ import annotations

import collections
import json
import logging
import threading
import time
from pathlib import Path

from companion.errors import CompanionError
from companion.view.channels import JSON, JSON_SCHEMAS, POSE, SCENE, TOPICS, TRANSFORMS, MessageBuilder
from companion.view.snapshot import Snapshots, TickSnapshot

logger = logging.getLogger(__name__)

#: Snapshots waiting for the publishing thread (at 20 Hz, 3.2 s).
QUEUE_SIZE = 64
#: Loopback by default: the view shows the vehicle's surroundings to whoever connects.
DEFAULT_HOST = "127.0.0.1"


class ViewUnavailable(CompanionError, RuntimeError):
    """The foxglove SDK is missing (install the ``view`` extra) or the server cannot start."""


def parse_endpoint(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` as (host, port); the host defaults to loopback. Raises ValueError."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    host = host.strip("[]") or DEFAULT_HOST
    value = int(port)
    if not 0 <= value <= 65535:
        raise ValueError(f"port {value} is not in 0..65535")
    return host, value


def _sdk():
    try:
        import foxglove
        import foxglove.channels  # noqa: F401
    except ImportError:
        raise ViewUnavailable("the Foxglove view needs the foxglove SDK: install the view extra "
                              "(pip install 'ogccmpc[view]')") from None
    return foxglove


class ViewPublisher:
    """Publishes each tick's snapshot to an MCAP file and/or a live Foxglove server.

    Parameters
    ----------
    mcap : path of the MCAP file to write (replaced if it exists), or None.
    server : (host, port) of the Foxglove WebSocket server to start (port 0: any free), or None.
    threaded : build and log the messages on this publisher's thread (live runs), else inline.
    time_offset_s : added to link time for stamps (a lockstep run: its tlog's epoch).
    queue_size : snapshots the thread may lag behind (the oldest is dropped beyond).
    """

    def __init__(self, *, mcap: str | Path | None = None, server: tuple[str, int] | None = None,
                 threaded: bool = False, time_offset_s: float = 0.0, queue_size: int = QUEUE_SIZE) -> None:
        foxglove = _sdk()
        self._foxglove = foxglove
        self.context = foxglove.Context()
        self.builder = MessageBuilder(time_offset_s)
        self.channels = self._channels()
        self.mcap_path = Path(mcap) if mcap is not None else None
        self._writer = foxglove.open_mcap(str(mcap), allow_overwrite=True, context=self.context) if mcap else None
        self.server = None
        if server is not None:
            host, port = server
            try:
                self.server = foxglove.start_server(name="companion", host=host, port=port, context=self.context)
            except Exception as exc:  # the SDK raises its own error types (port in use, bad host)
                self.close()
                raise ViewUnavailable(f"cannot start the Foxglove server on {host}:{port}: {exc}") from None
        self.snapshots = Snapshots()
        self.ticks = 0
        self.published = 0
        self.dropped = 0
        self.counts: collections.Counter[str] = collections.Counter()
        self.tick_cost_s = 0.0          # time spent in __call__ on the loop's thread
        self.tick_cost_max_s = 0.0
        self.thread_cpu_s = 0.0         # CPU of the publishing thread
        self._started = time.perf_counter()
        self._queue: collections.deque[TickSnapshot] = collections.deque(maxlen=max(1, int(queue_size)))
        self._wake = threading.Condition()
        self._closing = False
        self._thread = None
        if threaded:
            self._thread = threading.Thread(target=self._run, name="companion-view", daemon=True)
            self._thread.start()

    @property
    def port(self) -> int | None:
        """The live server's port (the one bound, when started on port 0)."""
        return None if self.server is None else int(self.server.port)

    def _channels(self) -> dict:
        fg = self._foxglove
        kinds = {SCENE: fg.channels.SceneUpdateChannel, POSE: fg.channels.PoseInFrameChannel,
                 TRANSFORMS: fg.channels.FrameTransformsChannel}
        out = {}
        for topic, (kind, schema) in TOPICS.items():
            if kind == JSON:
                out[topic] = fg.Channel(topic, schema=fg.Schema(name=schema, encoding="jsonschema",
                                                                data=json.dumps(JSON_SCHEMAS[schema]).encode()),
                                        message_encoding="json", context=self.context)
            else:
                out[topic] = kinds[kind](topic, context=self.context)
        return out

    # ------------------------------------------------------------------ the sink

    def __call__(self, companion, t_s: float, outbox) -> None:
        """After a tick: snapshot ``companion`` and publish it (inline) or queue it (threaded)."""
        start = time.perf_counter()
        snap = self.snapshots.take(companion, t_s, outbox)
        self.ticks += 1
        if self._thread is None:
            self._publish(snap)
        else:
            with self._wake:
                if len(self._queue) == self._queue.maxlen:
                    self.dropped += 1           # the deque drops its oldest on append
                self._queue.append(snap)
                self._wake.notify()
        cost = time.perf_counter() - start
        self.tick_cost_s += cost
        self.tick_cost_max_s = max(self.tick_cost_max_s, cost)

    def _publish(self, snap: TickSnapshot) -> None:
        log_time = self.builder.stamp_ns(snap.t_s)
        for topic, msg in self.builder.messages(snap):
            channel = self.channels[topic]
            if isinstance(msg, dict):
                channel.log(json.dumps(msg, allow_nan=False).encode(), log_time=log_time)
            else:
                channel.log(msg, log_time=log_time)
            self.counts[topic] += 1
            self.published += 1

    def _run(self) -> None:
        cpu0 = time.thread_time()
        while True:
            with self._wake:
                while not self._queue and not self._closing:
                    self._wake.wait(0.5)
                if not self._queue and self._closing:
                    break
                snap = self._queue.popleft()
            try:
                self._publish(snap)
            except Exception:  # the view must never take the loop down
                logger.exception("view: publishing a snapshot failed")
            self.thread_cpu_s = time.thread_time() - cpu0

    # ------------------------------------------------------------------ the end

    def close(self) -> None:
        """Publish what is queued, stop the thread and the server, finish the MCAP file; safe twice."""
        if self._thread is not None:
            with self._wake:
                self._closing = True
                self._wake.notify()
            self._thread.join(timeout=10.0)
            self._thread = None
        if getattr(self, "server", None) is not None:
            self.server.stop()
            self.server = None
        if getattr(self, "_writer", None) is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> "ViewPublisher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def summary(self, wall_s: float | None = None) -> dict:
        """What the view did and cost: ticks seen, messages per topic, drops, its CPU and share of the wall time."""
        wall = (time.perf_counter() - self._started) if wall_s is None else wall_s
        cpu = self.tick_cost_s + self.thread_cpu_s
        out = {
            "view_ticks": self.ticks,
            "view_messages": self.published,
            "view_dropped": self.dropped,
            "view_tick_cost_mean_ms": round(self.tick_cost_s / self.ticks * 1e3, 3) if self.ticks else None,
            "view_tick_cost_max_ms": round(self.tick_cost_max_s * 1e3, 3),
            "view_cpu_s": round(cpu, 3),
            "view_cpu_share": round(cpu / wall, 4) if wall > 0 else None,
            "view_channels": dict(self.counts),
        }
        if self.mcap_path is not None:
            out["mcap"] = str(self.mcap_path)
        return out
