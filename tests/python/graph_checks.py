"""Exact graph properties the tests check topologies against: eccentricities, centres, node
and edge connectivity (unit-capacity max-flow, Menger), quick for robot-team sizes (<= ~64)."""

from octofuse.fusion.graph import Graph, _cut_off, is_connected


def eccentricities(g: Graph) -> tuple[int, ...]:
    """Hop eccentricity of every node (longest shortest path from it); needs a connected graph."""
    if not is_connected(g):
        raise ValueError(f"eccentricities need a connected graph: {_cut_off(g)}")
    out = []
    for s in range(g.n):
        dist = {s: 0}
        frontier = [s]
        while frontier:
            nxt = []
            for u in frontier:
                for v in g.neighbors(u):
                    if v not in dist:
                        dist[v] = dist[u] + 1
                        nxt.append(v)
            frontier = nxt
        out.append(max(dist.values()))
    return tuple(out)


def centres(g: Graph) -> tuple[int, ...]:
    """Nodes whose eccentricity equals the radius."""
    ecc = eccentricities(g)
    return tuple(i for i, e in enumerate(ecc) if e == min(ecc))


def edge_connectivity(g: Graph) -> int:
    """Fewest edges whose removal disconnects ``g`` (0 if disconnected or n == 1)."""
    if g.n < 2 or not is_connected(g):
        return 0
    best = min(g.degrees())
    for t in range(1, g.n):
        # An undirected unit edge is two opposite unit arcs; residual bit u->v while flow(u,v) < 1.
        flow = [[0] * g.n for _ in range(g.n)]
        res = [sum(1 << v for v in g.neighbors(u)) for u in range(g.n)]
        value = 0
        while value < best and (path := _augmenting_path(res, 0, t)) is not None:
            for u, v in path:
                flow[u][v] += 1
                flow[v][u] -= 1
                if flow[u][v] >= 1:
                    res[u] &= ~(1 << v)
                res[v] |= 1 << u
            value += 1
        best = min(best, value)
    return best


def node_connectivity(g: Graph) -> int:
    """Fewest nodes whose removal disconnects ``g`` (n - 1 for a complete graph, 0 if
    disconnected). Even's algorithm: min local connectivity over non-adjacent pairs whose
    smaller node is among the first kappa + 1."""
    if g.n < 2 or not is_connected(g):
        return 0
    best = min(g.degrees())
    adjacent = [set(g.neighbors(i)) for i in range(g.n)]
    i = 0
    while i <= best and i < g.n:
        for j in range(i + 1, g.n):
            if j not in adjacent[i]:
                best = min(best, _local_node_connectivity(g, i, j, cap=best))
        i += 1
    return best


def _local_node_connectivity(g: Graph, s: int, t: int, cap: int) -> int:
    """Node-disjoint s-t paths (s, t non-adjacent), counted up to ``cap``. Each node v is split
    into v_in = v and v_out = v + n joined by a unit arc; unit arcs have no opposite twins here,
    so a residual graph is the arc set with used arcs reversed (one bitmask per node)."""
    n = g.n
    res = [0] * (2 * n)
    for v in range(n):
        if v not in (s, t):
            res[v] |= 1 << (v + n)
        for u in g.neighbors(v):
            res[v + n] |= 1 << u
    value = 0
    while value < cap and (path := _augmenting_path(res, s + n, t)) is not None:
        for u, v in path:
            res[u] &= ~(1 << v)
            res[v] |= 1 << u
        value += 1
    return value


def _augmenting_path(res: list[int], src: int, dst: int) -> list[tuple[int, int]] | None:
    """Breadth-first search on bitmask adjacency; the arcs of a shortest src-dst path or None."""
    parent = {src: src}
    visited = 1 << src
    frontier = [src]
    while frontier:
        nxt = []
        for u in frontier:
            new = res[u] & ~visited
            visited |= new
            while new:
                low = new & -new
                v = low.bit_length() - 1
                new ^= low
                parent[v] = u
                if v == dst:
                    path = []
                    while v != src:
                        path.append((parent[v], v))
                        v = parent[v]
                    return path
                nxt.append(v)
        frontier = nxt
    return None
