"""Communication graphs between agents.

A :class:`Graph` is an immutable undirected simple graph on the nodes ``0..n-1`` (one node per
agent, optionally named). :func:`make_graph` builds one from a short spec string:

==================  ===============================================================================
``ring``            cycle 0-1-...-(n-1)-0 (for n = 2 a single edge)
``line``            path 0-1-...-(n-1)
``star``            node 0 is the hub, linked to every other node
``complete``        every pair linked
``grid``            the most square r x c grid with r * c == n and 2 <= r <= c (8 -> 2 x 4), nodes
                    numbered row by row. A prime n has no such grid and is an error: ask for
                    ``grid:1xN`` (a single row, the same graph as ``line``) or another topology.
``grid:RxC``        an explicit R x C grid (R * C must equal n)
``random:P``        Erdos-Renyi G(n, P), drawn with ``numpy.random.default_rng(seed)``. A
                    disconnected draw is an error (never silently redrawn): raise P or change seed.
``max-robust:K``    the Harary graph H_{K,n}: K-connected with the fewest edges, ceil(K n / 2).
                    ``max-robust:3`` on 8 agents is the network of the paper (3-regular, node and
                    edge connectivity 3, every node a centre). K = 1 gives the path (a tree is the
                    1-connected graph with the fewest edges).
*path*              an edge-list text file (``a b`` per line, ``#`` comments) or a YAML file
                    (``.yaml``/``.yml``: ``nodes: [...]`` (optional), ``edges: [[a, b], ...]``).
==================  ===============================================================================

In files, a node is an agent name (from ``names``; for a YAML file without ``names``, its
``nodes`` list names the agents in order) or a 0-based agent index (the position in ``names``,
not in the file's ``nodes``); a name wins over an index when a name looks like a number. A YAML
``nodes`` list must cover every agent. Every graph :func:`make_graph` returns is connected.

"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

TOPOLOGIES = ("ring", "line", "star", "complete", "grid", "random:P", "max-robust:K")
GRAPH_FILE_SUFFIXES = (".txt", ".edges", ".edgelist", ".yaml", ".yml")


@dataclass(frozen=True)
class Graph:
    """Undirected simple graph on nodes ``0..n-1``.

    ``edges`` is normalised on construction to a sorted tuple of ``(a, b)`` with ``a < b``;
    self-loops, repeated edges and out-of-range nodes are rejected. ``spec`` records how the
    graph was made (for reports). Connectivity is not required here; :func:`make_graph` checks it.
    """

    n: int
    edges: tuple[tuple[int, int], ...] = ()
    names: tuple[str, ...] | None = None
    spec: str = ""
    _adj: tuple[tuple[int, ...], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = _check_int("n", self.n, minimum=1)
        normalised = set()
        for edge in self.edges:
            a, b = (int(v) for v in edge)
            if not (0 <= a < n and 0 <= b < n):
                raise ValueError(f"edge ({a}, {b}) has a node outside 0..{n - 1}")
            if a == b:
                raise ValueError(f"self-loop on node {a}")
            pair = (min(a, b), max(a, b))
            if pair in normalised:
                raise ValueError(f"duplicate edge {pair}")
            normalised.add(pair)
        edges = tuple(sorted(normalised))
        adj: list[list[int]] = [[] for _ in range(n)]
        for a, b in edges:
            adj[a].append(b)
            adj[b].append(a)
        object.__setattr__(self, "edges", edges)
        object.__setattr__(self, "_adj", tuple(tuple(sorted(nb)) for nb in adj))
        object.__setattr__(self, "n", n)
        object.__setattr__(self, "names", _check_names(self.names, n))

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    def neighbors(self, i: int) -> tuple[int, ...]:
        """Sorted neighbours of node ``i``."""
        return self._adj[i]

    def degree(self, i: int) -> int:
        return len(self._adj[i])

    def degrees(self) -> tuple[int, ...]:
        return tuple(len(nb) for nb in self._adj)

    def label(self, i: int) -> str:
        """Name of node ``i``, or its index as text for an unnamed graph."""
        return self.names[i] if self.names is not None else str(i)

    def adjacency_matrix(self) -> np.ndarray:
        """Symmetric ``(n, n)`` boolean adjacency matrix."""
        m = np.zeros((self.n, self.n), dtype=bool)
        if self.edges:
            a, b = np.array(self.edges).T
            m[a, b] = m[b, a] = True
        return m

    def to_dict(self) -> dict:
        """Plain-data form (JSON/YAML friendly); ``Graph(**g.to_dict())`` rebuilds it."""
        return {
            "n": self.n,
            "names": list(self.names) if self.names is not None else None,
            "edges": [list(e) for e in self.edges],
            "spec": self.spec,
        }


def make_graph(spec: str, n: int, *, seed: int = 0, names: Sequence[str] | None = None) -> Graph:
    """Build the connected communication graph described by ``spec`` on ``n`` agents.

    ``seed`` only matters for ``random:P``; ``names`` (one per agent) label the nodes and are how
    graph files refer to agents. Raises ``ValueError`` with an actionable message on any problem.
    """
    n = _check_int("n", n, minimum=1)
    if n < 2:
        raise ValueError(f"a communication graph needs at least 2 agents, got n={n}")
    names = _check_names(names, n)
    spec = str(spec).strip()
    kind, _, param = spec.partition(":")
    kind = kind.strip().lower()
    builders = {
        "ring": _ring,
        "line": _line,
        "star": _star,
        "complete": _complete,
        "grid": _grid,
        "random": _random,
        "max-robust": _max_robust,
    }
    if kind in builders:
        edges = builders[kind](n, param.strip(), seed)
        g = Graph(n, edges, names, spec)
    elif Path(spec).is_file():
        g = _from_file(Path(spec), n, names)
    elif spec.lower().endswith(GRAPH_FILE_SUFFIXES) or "/" in spec or "\\" in spec:
        raise ValueError(f"graph file not found: {spec}")
    else:
        raise ValueError(
            f"unknown topology {spec!r}; valid: {', '.join(TOPOLOGIES)}, or the path of an "
            "edge-list (.txt) or YAML (.yaml) graph file"
        )
    cut_off = _cut_off(g)
    if cut_off:
        where = f"random:{param.strip()} with n={n}, seed={seed}" if kind == "random" else spec
        hint = " (use a larger P or another seed)" if kind == "random" else ""
        raise ValueError(f"graph {where} is disconnected: {cut_off}{hint}")
    return g


# ---------------------------------------------------------------------------------- topologies


def _no_param(name: str, param: str) -> None:
    if param:
        raise ValueError(f"topology {name!r} takes no parameter, got {name}:{param}")


def _ring(n: int, param: str, seed: int) -> list[tuple[int, int]]:
    _no_param("ring", param)
    return sorted({(min(i, (i + 1) % n), max(i, (i + 1) % n)) for i in range(n)})


def _line(n: int, param: str, seed: int) -> list[tuple[int, int]]:
    _no_param("line", param)
    return [(i, i + 1) for i in range(n - 1)]


def _star(n: int, param: str, seed: int) -> list[tuple[int, int]]:
    _no_param("star", param)
    return [(0, i) for i in range(1, n)]


def _complete(n: int, param: str, seed: int) -> list[tuple[int, int]]:
    _no_param("complete", param)
    return [(i, j) for i in range(n) for j in range(i + 1, n)]


def _grid(n: int, param: str, seed: int) -> list[tuple[int, int]]:
    if param:
        m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", param)
        if not m:
            raise ValueError(f"grid size must look like RxC (e.g. grid:2x4), got grid:{param}")
        rows, cols = int(m[1]), int(m[2])
        if rows * cols != n:
            raise ValueError(f"grid:{rows}x{cols} has {rows * cols} nodes but n={n}")
    else:
        rows = max(r for r in range(1, math.isqrt(n) + 1) if n % r == 0)
        cols = n // rows
        if rows == 1:
            raise ValueError(
                f"grid: n={n} has no r x c factorisation with 2 <= r <= c; use grid:1x{n} for "
                "a single row (the same as line) or another topology"
            )
    edges = []
    for r in range(rows):
        for c in range(cols):
            i = r * cols + c
            if c + 1 < cols:
                edges.append((i, i + 1))
            if r + 1 < rows:
                edges.append((i, i + cols))
    return edges


def _random(n: int, param: str, seed: int) -> list[tuple[int, int]]:
    try:
        p = float(param)
    except ValueError:
        raise ValueError(
            f"random needs an edge probability, e.g. random:0.5, got random:{param}"
        ) from None
    if not 0.0 < p <= 1.0:
        raise ValueError(f"random:P needs 0 < P <= 1, got P={param}")
    seed = _check_int("seed", seed, minimum=0)
    rows, cols = np.triu_indices(n, k=1)
    keep = np.random.default_rng(seed).random(rows.size) < p
    return list(zip(rows[keep].tolist(), cols[keep].tolist()))


def _max_robust(n: int, param: str, seed: int) -> list[tuple[int, int]]:
    if not re.fullmatch(r"[+-]?\d+", param):
        raise ValueError(
            f"max-robust needs an integer connectivity K, e.g. max-robust:3, got max-robust:{param}"
        )
    k = int(param)
    if k < 1:
        raise ValueError(f"max-robust:K needs K >= 1, got K={k}")
    if k >= n:
        raise ValueError(
            f"max-robust:K needs K < n, got K={k} with n={n}; "
            f"the most connected is max-robust:{n - 1} (the complete graph)"
        )
    return harary_edges(k, n)


def harary_edges(k: int, n: int) -> list[tuple[int, int]]:
    """Edges of the Harary graph H_{k,n} (1 <= k < n), sorted; k = 1 gives the path.

    Even k: node i links to the k/2 nearest nodes on each side of a circle. Odd k: H_{k-1,n}
    plus diameters i -- i + n/2 for even n, or for odd n the chords i -- i + (n+1)/2 for
    i = 0..(n-1)/2 (node 0 gets two). Either way there are ceil(k n / 2) edges.
    """
    if not 1 <= k < n:
        raise ValueError(f"Harary graph H_(k,n) needs 1 <= k < n, got k={k}, n={n}")
    if k == 1:
        return [(i, i + 1) for i in range(n - 1)]
    edges = set()

    def link(a: int, b: int) -> None:
        a, b = a % n, b % n
        edges.add((min(a, b), max(a, b)))

    for i in range(n):
        for d in range(1, k // 2 + 1):
            link(i, i + d)
    if k % 2:
        if n % 2 == 0:
            for i in range(n // 2):
                link(i, i + n // 2)
        else:
            for i in range((n - 1) // 2 + 1):
                link(i, i + (n + 1) // 2)
    return sorted(edges)


# ------------------------------------------------------------------------------------- files


def _from_file(path: Path, n: int, names: tuple[str, ...] | None) -> Graph:
    if path.suffix.lower() in (".yaml", ".yml"):
        declared, raw_edges = _read_yaml(path)
    else:
        declared, raw_edges = None, _read_edge_list(path)
    if declared is not None and names is None:
        names = tuple(str(v) for v in declared)
        if len(names) != n:
            raise ValueError(f"{path}: declares {len(names)} nodes but n={n}")
        _check_names(names, n, where=f"{path}: nodes")
    lookup = {s: i for i, s in enumerate(names)} if names is not None else {}

    def resolve(token: object, where: str) -> int:
        text = str(token).strip()
        if text in lookup:
            return lookup[text]
        if re.fullmatch(r"\d+", text) and int(text) < n:
            return int(text)
        known = (
            f"known names: {', '.join(names)}"
            if names is not None
            else "no agent names were given, so nodes must be 0-based indices"
        )
        raise ValueError(f"{where}: unknown node {text!r} ({known}; or an index 0..{n - 1})")

    if declared is not None:
        listed = [resolve(v, f"{path}: nodes") for v in declared]
        missing = sorted(set(range(n)) - set(listed))
        if missing:
            labels = ", ".join(names[i] if names else str(i) for i in missing)
            raise ValueError(f"{path}: nodes does not list the agents {labels}")
    seen: dict[tuple[int, int], str] = {}
    edges = []
    for where, (a_tok, b_tok) in raw_edges:
        a, b = resolve(a_tok, where), resolve(b_tok, where)
        if a == b:
            raise ValueError(f"{where}: self-loop on node {a_tok!r}")
        pair = (min(a, b), max(a, b))
        if pair in seen:
            raise ValueError(f"{where}: duplicate edge {a_tok} -- {b_tok} (first at {seen[pair]})")
        seen[pair] = where
        edges.append(pair)
    return Graph(n, edges, names, str(path))


def _read_edge_list(path: Path) -> list[tuple[str, tuple[str, str]]]:
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        tokens = [t for t in re.split(r"[\s,]+", line.split("#", 1)[0]) if t]
        if not tokens:
            continue
        if len(tokens) != 2:
            raise ValueError(f"{path}:{lineno}: expected two nodes 'a b', got {line.strip()!r}")
        rows.append((f"{path}:{lineno}", (tokens[0], tokens[1])))
    return rows


def _read_yaml(path: Path) -> tuple[list | None, list[tuple[str, tuple]]]:
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise ValueError(f"{path}: not valid YAML ({err})") from None
    if not isinstance(doc, dict) or "edges" not in doc:
        raise ValueError(
            f"{path}: expected a mapping with 'edges: [[a, b], ...]' (and optional 'nodes')"
        )
    unknown = sorted(set(doc) - {"nodes", "edges"})
    if unknown:
        raise ValueError(f"{path}: unknown keys {unknown}; expected 'nodes' and 'edges'")
    nodes = doc.get("nodes")
    if nodes is not None and not (isinstance(nodes, list) and all(_is_token(v) for v in nodes)):
        raise ValueError(f"{path}: 'nodes' must be a list of names or indices")
    if nodes is not None and len({str(v) for v in nodes}) != len(nodes):
        raise ValueError(f"{path}: 'nodes' lists a node twice: {nodes}")
    if not isinstance(doc["edges"], list):
        raise ValueError(f"{path}: 'edges' must be a list of [a, b] pairs")
    rows = []
    for k, e in enumerate(doc["edges"]):
        if not (isinstance(e, list) and len(e) == 2 and all(_is_token(v) for v in e)):
            raise ValueError(f"{path}: edges[{k}] must be a pair [a, b], got {e!r}")
        rows.append((f"{path}: edges[{k}]", (e[0], e[1])))
    return nodes, rows


def _is_token(v: object) -> bool:
    return isinstance(v, str) or (isinstance(v, int) and not isinstance(v, bool))


# -------------------------------------------------------------------------------- properties


def components(g: Graph) -> list[tuple[int, ...]]:
    """Connected components as sorted node tuples, ordered by their smallest node."""
    seen = [False] * g.n
    out = []
    for s in range(g.n):
        if seen[s]:
            continue
        seen[s] = True
        comp, stack = [s], [s]
        while stack:
            for v in g.neighbors(stack.pop()):
                if not seen[v]:
                    seen[v] = True
                    comp.append(v)
                    stack.append(v)
        out.append(tuple(sorted(comp)))
    return out


def is_connected(g: Graph) -> bool:
    return len(components(g)) == 1


def _cut_off(g: Graph) -> str:
    """Empty if connected, else which nodes are cut off from node 0's component."""
    parts = components(g)
    if len(parts) == 1:
        return ""
    groups = ["{" + ", ".join(g.label(i) for i in comp) + "}" for comp in parts[1:]]
    return f"nodes {' '.join(groups)} are cut off from node {g.label(0)}"


# ----------------------------------------------------------------------------------- helpers


def _check_int(what: str, value: object, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{what} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{what} must be >= {minimum}, got {value}")
    return int(value)


def _check_names(
    names: Iterable[str] | None, n: int, where: str = "names"
) -> tuple[str, ...] | None:
    if names is None:
        return None
    names = tuple(names)
    if len(names) != n:
        raise ValueError(f"{where}: got {len(names)} names for n={n} agents")
    bad = [s for s in names if not isinstance(s, str) or not s.strip()]
    if bad:
        raise ValueError(f"{where}: names must be non-empty strings, got {bad}")
    dupes = sorted({s for s in names if names.count(s) > 1})
    if dupes:
        raise ValueError(f"{where}: names must be unique, repeated: {', '.join(dupes)}")
    return names
