"""One agent's Zenoh session: messages to its neighbours, its inbox, liveliness and status.

Peers meet on explicit endpoints (no multicast scouting): every agent listens on its own
endpoint and connects to its neighbours'. Messages go in chunks of a bounded size
(:mod:`.chunks`), put reliably with congestion control that blocks rather than drops, so loss
comes only from the network or the fault layer (:mod:`.faults`, which sees each chunk). What
arrives is put together and queued as it comes (Zenoh's callback threads) and taken by the
agent's loop; a chunk over the size bound is dropped and counted before it is copied.
"""

from __future__ import annotations

import json
import queue
import threading
import time

from ..config import LiveConfig
from . import keys
from .chunks import Reassembler, split


def endpoint(live: LiveConfig, index: int) -> str:
    """Where agent ``index`` (in the fleet's agents' order) listens."""
    return f"{live.scheme}/{live.host}:{live.base_port + index}"


def zenoh_config(live: LiveConfig, listen: str, connect: list[str]):
    """A Zenoh peer configuration: explicit endpoints, no scouting, TLS and user/password
    authentication as configured."""
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps([listen]))
    c.insert_json5("connect/endpoints", json.dumps(connect))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    if live.tls_root_ca:
        tls = {
            "root_ca_certificate": live.tls_root_ca,
            "listen_certificate": live.tls_certificate,
            "listen_private_key": live.tls_private_key,
            "connect_certificate": live.tls_certificate,
            "connect_private_key": live.tls_private_key,
            "enable_mtls": True,
        }
        for k, v in tls.items():
            c.insert_json5(f"transport/link/tls/{k}", json.dumps(v))
    if live.user:
        auth = {"user": live.user, "password": live.password}
        if live.users_file:
            auth["dictionary_file"] = live.users_file
        c.insert_json5("transport/auth/usrpwd", json.dumps(auth))
    return c


def open_session(live: LiveConfig, listen: str, connect: list[str], who: str):
    """A Zenoh peer session listening on ``listen``; ``OSError`` naming ``who`` and the
    endpoint if it cannot (a port taken, a certificate that does not load, ...)."""
    import zenoh

    try:
        return zenoh.open(zenoh_config(live, listen, connect))
    except zenoh.ZError as e:
        reason = str(e).split(" at /", 1)[0]
        raise OSError(f"{who}: Zenoh cannot listen on {listen}: {reason}") from None


class ZenohTransport:
    """Agent ``name``'s session in fleet ``live.fleet`` under ``rule``.

    ``inbox`` holds ``(sender, frame)`` in arrival order; :meth:`wait_for` returns
    once every neighbour has declared it listens."""

    def __init__(
        self,
        live: LiveConfig,
        rule: str,
        name: str,
        listen: str,
        connect: list[str],
        announce: bool = True,
    ):
        self.live, self.rule, self.name = live, rule, name
        self.inbox: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self.dropped = 0  #: chunks over the size bound
        self._number = 0  # this agent's messages, numbered for their chunks
        self._chunks = Reassembler(live.max_message_bytes)
        self._assembling = threading.Lock()
        self._alive: set[str] = set()
        self._alive_changed = threading.Condition()
        self.session = open_session(live, listen, connect, f"agent {name}")
        self._publishers: dict[str, object] = {}
        self._subscriber = self.session.declare_subscriber(
            keys.inbox(live.fleet, rule, name), self._on_message
        )
        prefix = keys.alive(live.fleet, rule, "")
        self._watch = self.session.liveliness().declare_subscriber(
            prefix + "*", self._on_alive, history=True
        )
        self._token = None
        if announce:
            self.announce()
        self._done: set[str] = set()
        self._done_token = None
        self._watch_done = self.session.liveliness().declare_subscriber(
            keys.done(live.fleet, rule, "*"), self._on_done, history=True
        )

    # -- messages ----------------------------------------------------------------------------
    def send(self, receiver: str, frame: bytes, put=None) -> None:
        """Send ``frame`` to ``receiver`` in chunks of at most ``live.max_chunk_bytes``, each
        through ``put(receiver, chunk)`` (default :meth:`put`; a fault layer goes there)."""
        self._number += 1
        for chunk in split(frame, self._number, self.live.max_chunk_bytes):
            (put or self.put)(receiver, chunk)

    def put(self, receiver: str, chunk: bytes) -> None:
        """Put ``chunk`` to ``receiver`` (reliably; blocks while the link is congested)."""
        import zenoh

        pub = self._publishers.get(receiver)
        if pub is None:
            pub = self._publishers[receiver] = self.session.declare_publisher(
                keys.message(self.live.fleet, self.rule, receiver, self.name),
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
            )
        pub.put(chunk)

    def _on_message(self, sample) -> None:
        payload = sample.payload
        if len(payload) > self.live.max_chunk_bytes:
            self.dropped += 1
            return
        sender = keys.sender_of(sample.key_expr)
        with self._assembling:  # Zenoh may call on several threads
            frame = self._chunks.add(sender, payload.to_bytes())
        if frame is not None:
            self.inbox.put((sender, frame))

    # -- who is there --------------------------------------------------------------------------
    def _on_alive(self, sample) -> None:
        import zenoh

        agent = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._alive_changed:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(agent)
            else:
                self._alive.discard(agent)
            self._alive_changed.notify_all()

    def wait_for(self, agents: list[str], timeout: float) -> None:
        """Return once every agent of ``agents`` listens; ``TimeoutError`` naming the missing
        ones after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        with self._alive_changed:
            while not set(agents) <= self._alive:
                left = deadline - time.monotonic()
                if left <= 0:
                    missing = sorted(set(agents) - self._alive)
                    raise TimeoutError(
                        f"agent {self.name}: no word from {', '.join(missing)} "
                        f"within {timeout:g} s (are they running, on the "
                        "fleet's endpoints?)"
                    )
                self._alive_changed.wait(left)

    @property
    def chunks_refused(self) -> int:
        """Chunks that were malformed or did not fit their message."""
        return self._chunks.dropped

    def announce(self) -> None:
        """Say that this agent listens (once every subscriber of its is declared)."""
        self._token = self.session.liveliness().declare_token(
            keys.alive(self.live.fleet, self.rule, self.name)
        )

    def _on_done(self, sample) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.PUT:
            self._done.add(str(sample.key_expr).rsplit("/", 1)[-1])

    def declare_done(self) -> None:
        """Say that this agent has sent everything it will."""
        self._done_token = self.session.liveliness().declare_token(
            keys.done(self.live.fleet, self.rule, self.name)
        )

    def running(self, agents: list[str]) -> list[str]:
        """The agents of ``agents`` that have not said they are done."""
        return [a for a in agents if a not in self._done]

    # -- what others see -------------------------------------------------------------------------
    def publish(self, key: str, payload: bytes) -> None:
        self.session.put(key, payload)

    def publish_status(self, status: dict) -> None:
        self.session.put(
            keys.status(self.live.fleet, self.rule, self.name), json.dumps(status).encode()
        )

    def close(self) -> None:
        held = (
            self._token,
            self._done_token,
            self._watch,
            self._watch_done,
            self._subscriber,
            *self._publishers.values(),
        )
        for x in (h for h in held if h is not None):
            try:
                x.undeclare()
            except Exception:  # noqa: BLE001 - the session closes them anyway
                pass
        self.session.close()
