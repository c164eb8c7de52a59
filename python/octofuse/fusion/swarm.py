"""The network in time with every agent in a Ray actor (``simulate_swarm``).

The in-process simulation (:func:`octofuse.fusion.simulate.simulate`) holds every map in one
process; a swarm of a few hundred agents does not fit one machine. Here the agents live in
Ray actors (workers, :mod:`.swarm_worker`), each holding its agents' maps (one per rule, the
local-only map and the accumulated information loss), and a message is what a robot would
send: the sender's map as an OctoMap ``.ot`` stream (:meth:`OccupancyMap.to_bytes`), carried by Ray's object store
straight from the sender's worker to the receiver's, wherever they run. The centralized map
lives in a worker of its own. The driver only reads the bags, hands each scan to its agent's
worker and tells senders and receivers when to act.

The schedule, the delivery rules and therefore the results are those of the in-process
simulation: events that share a time form a group; every message of a group carries its
sender's map as it was when the group started (the senders serialise before any receiver
fuses: Ray runs the calls of one submitter on one actor in submission order); a receiver fuses
its messages first in, first out; a scan stamped exactly at an exchange time is inserted
before it. With ``collect_maps`` the final maps come back as streams, equal byte for byte to
those of :func:`~octofuse.fusion.simulate.simulate`.

Agents may map in frames of their own (``fuse.agent_frames``), as in the simulation: a receiver
moves each message into its frame before fusing it, the centralized worker takes each scan moved
into the common frame, and scores compare the maps moved into it. With alignment on first
contact (``fuse.align``) a receiver registers its map against each message of a link not
aligned yet, before it fuses any message of the group, as the simulation does; the link's
transform stays with the receiver's worker. With deltas too, a link carries whole maps until
it aligns: the receiver's call returns the links that aligned, and the sender's next call on
such a link takes that result as an argument (Ray runs it once the result is there), so that
it knows which whole map its deltas start from.

The KL timeline (``samples`` points in time) is taken as in the simulation: at each point the
centralized worker sends its map as it is then, and every worker compares its maps with it.

The channel filter runs on its spanning tree, messages are lost as in the simulation (the
sender sends, the receiver never gets it), and robust fusion votes at its time on the robots'
own maps, gathered from the workers.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field

from ..config import CHANNEL_FILTER, BuildConfig, FuseConfig
from .agent_frames import AgentFrames
from .executors import ray_session
from .results import LOCAL, Traffic
from .robust import admitted, vote_for_run
from .schedule import EXCHANGE, VOTE, check_samples, moments, parse_schedule, run_schedule
from .swarm_worker import SwarmWorker


@dataclass
class SwarmResult:
    """What a swarm run produced (maps stay in the workers unless ``collect_maps``)."""

    agents: list[str]
    rules: list[str]
    graph: object
    events: list
    scores: dict  #: rule|local-only -> agent -> Score
    traffic: dict[str, Traffic]
    workers: list[dict]  #: per worker: agents, pid, rss, peak_rss, maps_bytes, seconds
    timings: dict[str, float] = field(default_factory=dict)
    messages: int = 0  #: messages delivered (one per event; each carries every rule's map)
    stream_bytes: int = 0  #: bytes of the .ot streams sent
    maps: dict | None = None  #: agent -> rule|local-only -> .ot bytes (collect_maps)
    central: bytes | None = None
    #: per link that received a message (with ``fuse.align``): as the simulation's ``alignment``
    alignment: list[dict] = field(default_factory=list)
    #: KL to the centralized map at ``samples`` points in time: as the simulation's ``timeline``
    timeline: list[dict] = field(default_factory=list)
    #: robust fusion's vote (with ``fuse.robust``): as the simulation's ``robust``
    robust: object | None = None
    #: frames the workers refused (malformed, or not for the agent that got them)
    dropped: int = 0

    @property
    def excluded(self) -> list[str]:
        """The robots robust fusion voted out."""
        return list(self.robust.excluded) if self.robust is not None else []

    @property
    def messages_per_second(self) -> float:
        """Messages delivered per second of the run (scans, exchanges and fusion overlap)."""
        t = self.timings.get("run (wall)", 0.0)
        return self.messages / t if t > 0 else float("nan")


def simulate_swarm(
    build_cfg: BuildConfig,
    fuse_cfg: FuseConfig,
    *,
    samples: int = 0,
    truth=None,
    agents_per_worker: int = 1,
    memory_per_worker: int | None = None,
    cpus_per_worker: float = 0.0,
    address: str | None = None,
    num_cpus: int | None = None,
    collect_maps: bool = False,
    max_in_flight: int | None = None,
    score: bool = True,
    log: Callable[[str], None] | None = None,
) -> SwarmResult:
    """Run the network in time with the agents in Ray actors (see the module's docstring).

    ``agents_per_worker`` agents share one actor process (1: an actor per agent);
    ``memory_per_worker`` (bytes) is both reserved from Ray's memory resource for each worker
    (so a node holds no more workers than fit) and enforced by the worker on its resident
    memory; ``cpus_per_worker`` CPUs are reserved per worker (0: workers mostly wait, so many
    share a core). A local Ray (``num_cpus`` CPUs) is started unless one is running or
    ``address`` names a cluster. ``max_in_flight`` bounds the calls submitted and not yet
    finished (default: 4 per worker). ``score=False`` skips the scores (each agent's map is
    compared with the whole centralized map: on a large floor that dominates the time), as
    ``samples=0`` (the default) skips the KL timeline.
    """
    from ..scans.source import ScanSource, prefetch

    spec = parse_schedule(fuse_cfg.schedule)
    if spec.kind == "rounds":
        raise ValueError(
            "a swarm runs in time: the schedule must be aperiodic:MEAN_S or periodic:PERIOD_S"
        )
    if agents_per_worker < 1:
        raise ValueError(f"agents_per_worker must be >= 1, got {agents_per_worker}")
    check_samples(samples)
    say = log or (lambda _m: None)
    rules = list(fuse_cfg.rules)
    t_all = time.perf_counter()
    timings: dict[str, float] = defaultdict(float)
    with ray_session(address, num_cpus) as ray, ScanSource(build_cfg) as src:
        agents = [a.name for a in src.agents]
        frames = AgentFrames.from_config(agents, fuse_cfg)
        start = src.bags.start_ns
        graph, duration, events = run_schedule(fuse_cfg, agents, start, src.bags.end_ns)
        tree: list[tuple[str, str]] = []
        if CHANNEL_FILTER in rules:
            from .channel_filter import spanning_tree

            for a, b in spanning_tree(graph, fuse_cfg.spanning_tree):
                tree += [(agents[a], agents[b]), (agents[b], agents[a])]

        opts: dict = {"num_cpus": cpus_per_worker, "max_restarts": 0}
        if memory_per_worker:
            opts["memory"] = int(memory_per_worker)
        Worker = ray.remote(SwarmWorker).options(**opts)
        threads = max(1, int(cpus_per_worker)) if cpus_per_worker >= 1 else 1
        n_workers = math.ceil(len(agents) / agents_per_worker)
        have = ray.cluster_resources().get("memory", 0)
        if memory_per_worker and not address and memory_per_worker * (n_workers + 1) > have:
            raise ValueError(
                f"{n_workers + 1} workers of {memory_per_worker / 2**20:.0f} MiB need "
                f"{memory_per_worker * (n_workers + 1) / 2**30:.1f} GiB; this Ray has "
                f"{have / 2**30:.1f} GiB of memory resource: put more agents in a worker, lower "
                "the cap or join a cluster"
            )
        groups = [
            agents[w * agents_per_worker : (w + 1) * agents_per_worker] for w in range(n_workers)
        ]
        t0 = time.perf_counter()
        workers = [
            Worker.remote(
                w,
                names,
                build_cfg.map,
                rules,
                fuse_cfg.unknown,
                fuse_cfg.delta,
                threads,
                memory_per_worker,
                frames=frames,
                tree=tree,
                reliable=fuse_cfg.loss == 0,
                insert_mode=build_cfg.insert_mode,
                layers_max_bytes=fuse_cfg.layers_max_bytes,
            )
            for w, names in enumerate(groups)
        ]
        central = (
            ray.remote(SwarmWorker)
            .options(**opts)
            .remote(
                n_workers,
                [],
                build_cfg.map,
                [],
                fuse_cfg.unknown,
                False,
                threads,
                None,
                True,
                insert_mode=build_cfg.insert_mode,
            )
        )
        ray.get([w.stats.remote() for w in workers] + [central.stats.remote()])
        timings["start workers"] = time.perf_counter() - t0
        say(f"swarm: {len(agents)} agents in {n_workers} worker(s) + 1 for the centralized map")
        home = {a: workers[i // agents_per_worker] for i, a in enumerate(agents)}

        traffic = {r: Traffic() for r in rules}
        buffers: dict[int, list] = defaultdict(list)
        all_scans: list = []
        in_flight: list = []

        window = max_in_flight or 4 * (n_workers + 1)

        def bound() -> None:
            """Wait for the oldest calls while too many are in flight (bounds the object
            store's use; a worker's error surfaces here)."""
            while len(in_flight) > window:
                done, _ = ray.wait(in_flight[: len(in_flight) - window], num_returns=1)
                for ref in done:
                    ray.get(ref)
                    in_flight.remove(ref)

        def flush() -> None:
            for w, scans in buffers.items():
                if scans:
                    in_flight.append(workers[w].insert.remote(scans))
            if all_scans:
                in_flight.append(central.insert.remote(list(all_scans)))
            buffers.clear()
            all_scans.clear()
            bound()

        delivered = [0]
        # with alignment and deltas: per link not known to have aligned, the receivers' calls
        # its sender has still to see, and those calls not yet read here
        news: dict[tuple[str, str], list] = defaultdict(list)
        unread: list = []
        aligned_links: set[tuple[str, str]] = set()
        track = fuse_cfg.align != "off" and fuse_cfg.delta

        def read_news() -> None:
            """The links that aligned, from the receivers' calls that have finished."""
            if unread:
                done, _ = ray.wait(list(unread), num_returns=len(unread), timeout=0)
                for ref in done:
                    aligned_links.update(map(tuple, ray.get(ref)))
                    unread.remove(ref)

        def exchange(group) -> None:
            # no waiting: the calls of one submitter on one actor run in submission order,
            # so every send, receive and insertion happens in the schedule's order, and
            # groups on different workers overlap
            flush()
            t1 = time.perf_counter()
            receivers_of: dict[str, list[str]] = {}
            for e in group:
                receivers_of.setdefault(agents[e.sender], []).append(agents[e.receiver])
            refs: dict[tuple[str, str], object] = {}
            read_news()
            for s, recv in receivers_of.items():  # every sender before any receiver
                seen = list(dict.fromkeys(r for d in recv for r in news.pop((s, d), ())))
                if len(recv) > 1:
                    out = home[s].send.options(num_returns=len(recv)).remote(s, recv, *seen)
                else:
                    out = [home[s].send.remote(s, recv, *seen)]
                for d, ref in zip(recv, out):
                    refs[(s, d)] = ref
            inbox: dict[str, list] = {}
            for e in group:
                s, d = agents[e.sender], agents[e.receiver]
                if e.lost:  # sent, never received
                    in_flight.append(refs[(s, d)])
                    for r in rules:
                        if r != CHANNEL_FILTER or (s, d) in tree:
                            traffic[r].lost += 1
                    continue
                inbox.setdefault(d, []).append(s)
            for d, senders in inbox.items():
                ref = home[d].receive.remote(
                    d, senders, group[0].time_s, *[refs[(s, d)] for s in senders]
                )
                in_flight.append(ref)
                if track:
                    unread.append(ref)
                    for s in senders:
                        if (s, d) not in aligned_links:
                            news[(s, d)].append(ref)
            delivered[0] += len(group)
            timings["exchange calls (driver)"] += time.perf_counter() - t1
            bound()

        taken: list = []  # per sample, each worker's points of the timeline

        def sample(t: float) -> None:
            flush()
            cref = central.central_bytes.remote()
            parts = [w.sample.remote(cref, fuse_cfg.overconfidence_tol, t) for w in workers]
            taken.append(parts)
            in_flight.extend(parts)
            bound()

        vote: list = []  # robust fusion: the vote, once taken

        def take_vote(t: float) -> None:
            """Robust fusion's vote on the robots' own maps, gathered from the workers."""
            from ..maps.occupancy import OccupancyMap

            flush()
            ray.get(in_flight)
            in_flight.clear()
            own = {
                a: m
                for part in ray.get([w.own_maps.remote() for w in workers])
                for a, m in part.items()
            }
            vote.append(
                vote_for_run(
                    {a: frames.to_common(a, OccupancyMap.from_bytes(own[a])) for a in agents},
                    graph,
                    fuse_cfg,
                    t,
                )
            )

        timed = moments(
            events,
            duration,
            samples,
            vote_time=min(fuse_cfg.robust.time, duration) if fuse_cfg.robust.enabled else None,
        )
        next_i = 0
        pending = 0

        def advance(until: float) -> None:
            nonlocal next_i, pending
            while next_i < len(timed) and timed[next_i][0] < until:
                t, kind, group = timed[next_i]
                if kind == VOTE:
                    take_vote(t)
                elif kind == EXCHANGE:
                    group = admitted(group, vote[0] if vote else None, fuse_cfg, agents)
                    if group:
                        exchange(group)
                else:
                    sample(t)
                next_i += 1
                pending = 0

        t_loop = time.perf_counter()
        for scan in prefetch(src.scans()):
            t = (scan.stamp_ns - start) / 1e9
            advance(t)
            name = agents[scan.agent]
            buffers[scan.agent // agents_per_worker].append((name, scan))
            all_scans.append((name, frames.scan_in_common(scan)))
            pending += 1
            if pending >= build_cfg.batch_size * max(1, n_workers):
                flush()
                pending = 0
        advance(math.inf)
        flush()
        ray.get(in_flight)
        in_flight.clear()
        src.check_placed()
        timings["run (wall)"] = time.perf_counter() - t_loop

        t0 = time.perf_counter()
        cbytes = ray.get(central.central_bytes.remote()) if score or collect_maps else None
        scores: dict = {}
        if score:
            cref, truth_ref = ray.put(cbytes), ray.put(truth)
            parts = ray.get(
                [w.score.remote(cref, fuse_cfg.overconfidence_tol, truth_ref) for w in workers]
            )
            for p in parts:
                for r, per in p.items():
                    scores.setdefault(r, {}).update(per)
            scores = {r: {a: scores[r][a] for a in agents} for r in [LOCAL, *rules]}
        timings["final scores (wall)"] = time.perf_counter() - t0
        for p in ray.get([w.traffic.remote() for w in workers]):
            for r, t in p.items():
                tr = traffic[r]
                for k in ("sent", "received", "sent_32b"):
                    for a, v in t[k].items():
                        getattr(tr, k)[a] += v
                tr.messages += t["messages"]
        stats = ray.get([w.stats.remote() for w in workers] + [central.stats.remote()])
        alignment = sorted(
            (d for part in ray.get([w.alignment.remote() for w in workers]) for d in part),
            key=lambda d: (d["sender"], d["receiver"]),
        )
        timeline = []
        for parts in taken:  # in the simulation's order: time, rule, agent
            got = {(p["rule"], p["agent"]): p for part in ray.get(parts) for p in part}
            timeline += [got[r, a] for r in [LOCAL, *rules] for a in agents]
        maps = None
        if collect_maps:
            maps = {}
            for p in ray.get([w.maps.remote() for w in workers]):
                maps.update(p)
        for w in [*workers, central]:
            ray.kill(w)
    timings["total"] = time.perf_counter() - t_all
    return SwarmResult(
        agents,
        rules,
        graph,
        events,
        scores,
        traffic,
        stats,
        dict(timings),
        messages=delivered[0],
        stream_bytes=sum(s["stream_bytes_sent"] for s in stats),
        maps=maps,
        central=cbytes if collect_maps else None,
        alignment=alignment,
        timeline=timeline,
        robust=vote[0] if vote else None,
        dropped=sum(s["dropped"] for s in stats),
    )
