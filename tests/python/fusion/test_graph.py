import dataclasses
import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import graph_checks  # noqa: E402
from octofuse.fusion import graph  # noqa: E402

make_graph = graph.make_graph
Graph = graph.Graph

SETTINGS = settings(database=None, deadline=None)


def connectivities(g):
    return graph_checks.node_connectivity(g), graph_checks.edge_connectivity(g)


# ------------------------------------------------------------------------- simple topologies


@pytest.mark.parametrize(
    "spec, n, n_edges, degrees",
    [
        ("ring", 8, 8, [2] * 8),
        ("ring", 3, 3, [2] * 3),
        ("ring", 2, 1, [1, 1]),
        ("line", 8, 7, [1] + [2] * 6 + [1]),
        ("star", 8, 7, [7] + [1] * 7),
        ("complete", 8, 28, [7] * 8),
        ("complete", 2, 1, [1, 1]),
        ("grid", 8, 10, [2, 3, 3, 2, 2, 3, 3, 2]),  # 2 x 4
        ("grid", 9, 12, [2, 3, 2, 3, 4, 3, 2, 3, 2]),  # 3 x 3
        ("grid", 12, 17, [2, 3, 3, 2, 3, 4, 4, 3, 2, 3, 3, 2]),  # 3 x 4
        ("grid:4x2", 8, 10, [2, 2, 3, 3, 3, 3, 2, 2]),
        ("grid:1x7", 7, 6, [1] + [2] * 5 + [1]),
        ("max-robust:3", 8, 12, [3] * 8),
        ("max-robust:1", 6, 5, [1, 2, 2, 2, 2, 1]),
    ],
)
def test_builtin_topologies_edges_and_degrees(spec, n, n_edges, degrees):
    g = make_graph(spec, n)
    assert g.n == n and g.n_edges == n_edges and list(g.degrees()) == degrees
    assert list(g.edges) == sorted(g.edges) and all(a < b for a, b in g.edges)
    assert all(g.degree(i) == len(g.neighbors(i)) for i in range(n))
    assert graph.is_connected(g) and g.spec == spec


def test_known_shapes():
    assert make_graph("star", 5).neighbors(0) == (1, 2, 3, 4)
    assert make_graph("ring", 5).neighbors(0) == (1, 4)
    assert make_graph("grid", 8).neighbors(1) == (0, 2, 5)  # row-major 2 x 4
    assert graph_checks.eccentricities(make_graph("ring", 8)) == (4,) * 8
    assert graph_checks.eccentricities(make_graph("star", 6)) == (1,) + (2,) * 5
    assert graph_checks.eccentricities(make_graph("line", 5)) == (4, 3, 2, 3, 4)
    assert graph_checks.centres(make_graph("line", 5)) == (2,)
    assert make_graph("grid:1x7", 7).edges == make_graph("line", 7).edges
    assert make_graph("max-robust:1", 7).edges == make_graph("line", 7).edges
    assert make_graph("max-robust:2", 9).edges == make_graph("ring", 9).edges
    assert make_graph("max-robust:7", 8).edges == make_graph("complete", 8).edges
    assert make_graph("max-robust:8", 9).edges == make_graph("complete", 9).edges
    assert make_graph(" Ring ", 4).edges == make_graph("ring", 4).edges


# ------------------------------------------------------------------------------- max-robust


def test_paper_network_h38():
    g = make_graph("max-robust:3", 8)
    # the Wagner graph: an 8-cycle plus its four diameters
    assert g.edges == tuple(
        sorted(
            [(i, (i + 1) % 8) if i < 7 else (0, 7) for i in range(8)]
            + [(i, i + 4) for i in range(4)]
        )
    )
    assert g.degrees() == (3,) * 8
    assert connectivities(g) == (3, 3)
    ecc = graph_checks.eccentricities(g)
    assert ecc == (2,) * 8 and graph_checks.centres(g) == tuple(range(8))
    # symmetric: the rotation i -> i + 1 is an automorphism, so all nodes look alike
    rotated = {tuple(sorted(((a + 1) % 8, (b + 1) % 8))) for a, b in g.edges}
    assert rotated == set(g.edges)


@pytest.mark.parametrize("n", range(4, 33))
def test_max_robust_structure(n):
    for k in range(2, n):
        g = make_graph(f"max-robust:{k}", n)
        assert g.n_edges == -(-k * n // 2)  # ceil(k n / 2): the fewest for min degree k
        degrees = sorted(g.degrees())
        if k % 2 and n % 2:
            assert degrees == [k] * (n - 1) + [k + 1]
        else:
            assert degrees == [k] * n


@pytest.mark.parametrize("n", range(4, 13))
def test_max_robust_connectivity_small_exhaustive(n):
    for k in range(2, n):
        g = make_graph(f"max-robust:{k}", n)
        assert connectivities(g) == (k, k) and min(g.degrees()) == k


@SETTINGS
@given(st.integers(4, 32).flatmap(lambda n: st.tuples(st.just(n), st.integers(2, n - 1))))
def test_max_robust_connectivity_property(n_k):
    n, k = n_k
    g = make_graph(f"max-robust:{k}", n)
    assert (
        graph_checks.node_connectivity(g)
        == graph_checks.edge_connectivity(g)
        == min(g.degrees())
        == k
    )
    assert g.n_edges == -(-k * n // 2)


# ----------------------------------------------------------------------------------- random


def test_random_is_seeded_and_reproducible():
    a = make_graph("random:0.5", 12, seed=3)
    assert a == make_graph("random:0.5", 12, seed=3)
    assert any(make_graph("random:0.5", 12, seed=s).edges != a.edges for s in range(4, 10))
    assert make_graph("random:1", 6).edges == make_graph("complete", 6).edges
    big = make_graph("random:0.5", 40, seed=1)
    assert abs(big.n_edges - 0.5 * 40 * 39 / 2) < 60  # ~ 4.5 standard deviations


def test_random_disconnected_draw_is_an_error():
    with pytest.raises(ValueError) as err:
        make_graph("random:0.05", 20, seed=7)
    msg = str(err.value)
    for part in ("random:0.05", "n=20", "seed=7", "cut off", "larger P", "another seed"):
        assert part in msg


# ------------------------------------------------------------------------------------ files


NAMES = ["alpha", "bravo", "charlie", "delta"]


def test_edge_list_file_with_names_and_indices(tmp_path):
    f = tmp_path / "net.txt"
    f.write_text("# a ring of four\nalpha bravo\n\n bravo  charlie # inline\ncharlie,delta\n3 0\n")
    g = make_graph(str(f), 4, names=NAMES)
    assert g.edges == ((0, 1), (0, 3), (1, 2), (2, 3))
    assert g.names == tuple(NAMES) and g.label(3) == "delta"
    # names map to agents whatever their order; bare indices stay indices
    h = make_graph(str(f), 4, names=["delta", "alpha", "charlie", "bravo"])
    assert h.edges == ((0, 2), (0, 3), (1, 3), (2, 3))


def test_edge_list_file_with_indices_only(tmp_path):
    f = tmp_path / "net.edges"
    f.write_text("0 1\n1 2\n")
    assert make_graph(str(f), 3).edges == ((0, 1), (1, 2))


def test_yaml_file_names(tmp_path):
    f = tmp_path / "net.yaml"
    f.write_text(
        "nodes: [alpha, bravo, charlie, delta]\nedges: [[alpha, bravo], [bravo, charlie], [delta, alpha], [charlie, 3]]\n"
    )
    g = make_graph(str(f), 4, names=NAMES)
    assert g.edges == ((0, 1), (0, 3), (1, 2), (2, 3))
    # without agent names the file's node list names them, in order
    assert make_graph(str(f), 4).names == tuple(NAMES)
    # agents passed in another order map by name
    shuffled = ["delta", "charlie", "bravo", "alpha"]
    h = make_graph(str(f), 4, names=shuffled)
    assert h.edges == ((0, 3), (1, 2), (1, 3), (2, 3))  # 3 is an agent index: alpha here
    assert {frozenset((h.label(a), h.label(b))) for a, b in h.edges} == {
        frozenset(p)
        for p in [
            ("alpha", "bravo"),
            ("bravo", "charlie"),
            ("delta", "alpha"),
            ("charlie", "alpha"),
        ]
    }


def test_yaml_without_nodes(tmp_path):
    f = tmp_path / "net.yml"
    f.write_text("edges:\n  - [0, 1]\n  - [1, 2]\n")
    assert make_graph(str(f), 3).edges == ((0, 1), (1, 2))


@pytest.mark.parametrize(
    "suffix, text, names, expected",
    [
        (
            ".txt",
            "alpha bravo\nbravo echo\n",
            NAMES,
            ["'echo'", "known names: alpha, bravo, charlie, delta"],
        ),
        (".txt", "alpha bravo\n", None, ["'alpha'", "no agent names were given"]),
        (".txt", "0 1\n1 7\n", None, ["'7'", "0..3"]),
        (".txt", "alpha bravo\nbravo bravo\n", NAMES, [":2", "self-loop"]),
        (".txt", "alpha bravo\nbravo alpha\n", NAMES, [":2", "duplicate edge", ":1"]),
        (".txt", "alpha bravo charlie\n", NAMES, [":1", "expected two nodes"]),
        (
            ".txt",
            "alpha bravo\ncharlie delta\n",
            NAMES,
            ["disconnected", "{charlie, delta}", "cut off from node alpha"],
        ),
        (
            ".yaml",
            "nodes: [alpha, bravo]\nedges: [[alpha, bravo]]\n",
            NAMES,
            ["does not list the agents charlie, delta"],
        ),
        (
            ".yaml",
            "nodes: [a, b, c]\nedges: [[a, b], [b, c]]\n",
            None,
            ["declares 3 nodes but n=4"],
        ),
        (".yaml", "edges: [[alpha, bravo, charlie]]\n", NAMES, ["edges[0] must be a pair"]),
        (".yaml", "edge: [[alpha, bravo]]\n", NAMES, ["'edges"]),
        (".yaml", "edges: [[alpha, bravo]]\nnode: [alpha]\n", NAMES, ["unknown keys ['node']"]),
        (".yaml", "edges: [[a, b]\n", NAMES, ["not valid YAML"]),
        (".yaml", "nodes: [a, a, b, c]\nedges: [[a, b]]\n", None, ["lists a node twice"]),
    ],
)
def test_file_errors(tmp_path, suffix, text, names, expected):
    f = tmp_path / f"net{suffix}"
    f.write_text(text)
    with pytest.raises(ValueError) as err:
        make_graph(str(f), 4, names=names)
    assert str(f) in str(err.value)
    for part in expected:
        assert part in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(ValueError, match="graph file not found"):
        make_graph(str(tmp_path / "nope.yaml"), 4)


# ----------------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    "spec, n, expected",
    [
        (
            "torus",
            8,
            "unknown topology 'torus'; valid: ring, line, star, complete, grid, random:P, max-robust:K",
        ),
        ("ring:3", 8, "takes no parameter"),
        ("complete:1", 8, "takes no parameter"),
        ("max-robust:8", 8, "K < n, got K=8 with n=8; the most connected is max-robust:7"),
        ("max-robust:0", 8, "K >= 1"),
        ("max-robust:-2", 8, "K >= 1"),
        ("max-robust:2.5", 8, "integer connectivity K"),
        ("max-robust", 8, "integer connectivity K"),
        ("random:0", 8, "0 < P <= 1"),
        ("random:1.5", 8, "0 < P <= 1"),
        ("random:-0.1", 8, "0 < P <= 1"),
        ("random:nan", 8, "0 < P <= 1"),
        ("random:half", 8, "edge probability"),
        ("random", 8, "edge probability"),
        ("ring", 1, "at least 2 agents, got n=1"),
        ("grid", 7, "n=7 has no r x c factorisation"),
        ("grid:2x3", 8, "has 6 nodes but n=8"),
        ("grid:2by4", 8, "RxC"),
    ],
)
def test_spec_errors(spec, n, expected):
    with pytest.raises(ValueError) as err:
        make_graph(spec, n)
    assert expected in str(err.value)


@pytest.mark.parametrize(
    "kwargs, expected",
    [
        (dict(n=2.0), "n must be an integer"),
        (dict(n=True), "n must be an integer"),
        (dict(n=0), "n must be >= 1"),
        (dict(n=3, names=["a", "b"]), "got 2 names for n=3"),
        (dict(n=3, names=["a", "b", "a"]), "repeated: a"),
        (dict(n=2, names=["a", ""]), "non-empty strings"),
    ],
)
def test_argument_errors(kwargs, expected):
    with pytest.raises(ValueError, match=expected):
        make_graph("ring", **kwargs)


def test_random_seed_must_be_non_negative():
    with pytest.raises(ValueError, match="seed must be >= 0"):
        make_graph("random:0.5", 5, seed=-1)


# ------------------------------------------------------------------------------------ Graph


def test_graph_normalises_and_is_immutable():
    g = Graph(4, [(3, 2), [1, 0], (2, 1)], names=["a", "b", "c", "d"])
    assert g.edges == ((0, 1), (1, 2), (2, 3)) and g.neighbors(1) == (0, 2)
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.n = 5
    assert Graph(**g.to_dict()) == g
    assert g.to_dict() == {
        "n": 4,
        "names": ["a", "b", "c", "d"],
        "edges": [[0, 1], [1, 2], [2, 3]],
        "spec": "",
    }
    m = g.adjacency_matrix()
    assert (m == m.T).all() and m.sum(axis=1).tolist() == list(g.degrees())


@pytest.mark.parametrize(
    "edges, expected",
    [
        ([(0, 0)], "self-loop on node 0"),
        ([(0, 1), (1, 0)], r"duplicate edge \(0, 1\)"),
        ([(0, 3)], "outside 0..2"),
    ],
)
def test_graph_rejects_bad_edges(edges, expected):
    with pytest.raises(ValueError, match=expected):
        Graph(3, edges)


def test_disconnected_graph_properties():
    g = Graph(5, [(0, 1), (2, 3)])
    assert not graph.is_connected(g)
    assert graph.components(g) == [(0, 1), (2, 3), (4,)]
    assert connectivities(g) == (0, 0)
    with pytest.raises(ValueError, match=r"nodes \{2, 3\} \{4\} are cut off from node 0"):
        graph_checks.eccentricities(g)
    assert connectivities(Graph(1)) == (0, 0)


# ------------------------------------------------- connectivity against brute force (small graphs)


def _brute_connectivity(n, edges):
    """Node and edge connectivity straight from the definitions (fine for n <= 8)."""

    def connected(nodes, edge_list):
        nodes = set(nodes)
        seen, stack = {min(nodes)}, [min(nodes)]
        while stack:
            u = stack.pop()
            for a, b in edge_list:
                for x, y in ((a, b), (b, a)):
                    if x == u and y in nodes and y not in seen:
                        seen.add(y)
                        stack.append(y)
        return seen == nodes

    if not connected(range(n), edges):
        return 0, 0
    if len(edges) == n * (n - 1) // 2:
        kappa = n - 1
    else:  # the smallest node set whose removal leaves a disconnected graph
        kappa = next(
            size
            for size in range(n)
            for cut in itertools.combinations(range(n), size)
            if not connected(
                set(range(n)) - set(cut), [e for e in edges if e[0] not in cut and e[1] not in cut]
            )
        )
    # the smallest number of edges across a split of the nodes into two non-empty sides
    lam = min(
        sum((a in side) != (b in side) for a, b in edges)
        for size in range(1, n)
        for side in map(set, itertools.combinations(range(n), size))
    )
    return kappa, lam


@SETTINGS
@given(
    st.integers(2, 8).flatmap(
        lambda n: st.tuples(
            st.just(n), st.sets(st.sampled_from(list(itertools.combinations(range(n), 2))))
        )
    )
)
def test_connectivity_matches_brute_force(n_edges):
    n, edges = n_edges
    edges = sorted(edges)
    assert connectivities(Graph(n, edges)) == _brute_connectivity(n, edges)
