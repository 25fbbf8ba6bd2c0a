"""`CovisibilityGraph`: weighted links between keyframes, edges, and the spanning tree."""

import numpy as np
import pytest
from map_fixtures import assert_tree, reaches_root

from pld_slam.mapping.covisibility import CovisibilityGraph


def graph_of(n_keyframes: int, min_shared: int = 20) -> CovisibilityGraph:
    """Keyframes 0 .. n-1 without links."""
    graph = CovisibilityGraph(min_shared)
    for keyframe in range(n_keyframes):
        graph.add_keyframe(keyframe)
    return graph


def set_links(graph: CovisibilityGraph, keyframe: int, shared: dict[int, int]) -> None:
    """Bring the links of ``keyframe`` to ``shared`` through `CovisibilityGraph.change_shared`, as
    observations added and removed do, then attach it to the spanning tree."""
    current = graph.shared(keyframe)
    for other in sorted(current.keys() | shared.keys()):
        graph.change_shared(keyframe, [other], shared.get(other, 0) - current.get(other, 0))
    graph.attach_to_tree(keyframe)


# --- links and edges ------------------------------------------------------------------


def test_a_link_needs_min_shared_landmarks_to_be_an_edge():
    graph = graph_of(4, min_shared=20)
    set_links(graph, 3, {0: 20, 1: 19, 2: 45})
    assert graph.neighbours(3) == [2, 0]
    assert graph.shared(3) == {0: 20, 1: 19, 2: 45}  # the weak link is still known


def test_a_keyframe_whose_links_are_all_weaker_than_min_shared_keeps_its_strongest_as_only_edge():
    graph = graph_of(4, min_shared=20)
    set_links(graph, 3, {0: 5, 1: 12, 2: 7})
    assert graph.neighbours(3) == [1]
    # For keyframe 1 the link to 3 is also its strongest (its only one): an edge both ways.
    assert graph.neighbours(1) == [3]


def test_a_keyframe_without_links_has_no_neighbours():
    graph = graph_of(2)
    assert graph.neighbours(1) == []
    assert graph.shared(1) == {}


def test_neighbours_come_strongest_first_with_ties_to_the_lower_id_and_respect_the_limit():
    graph = graph_of(6, min_shared=10)
    set_links(graph, 5, {4: 30, 1: 50, 3: 30, 0: 10, 2: 9})
    assert graph.neighbours(5) == [1, 3, 4, 0]
    assert graph.neighbours(5, limit=2) == [1, 3]
    assert graph.neighbours(5, limit=10) == [1, 3, 4, 0]


def test_links_are_symmetric():
    graph = graph_of(4)
    set_links(graph, 2, {0: 25, 1: 30})
    set_links(graph, 3, {2: 40})
    assert graph.shared(0) == {2: 25}
    assert graph.shared(1) == {2: 30}
    assert graph.shared(2) == {0: 25, 1: 30, 3: 40}
    assert graph.shared(3) == {2: 40}


def test_changing_links_changes_both_sides_and_drops_a_link_that_falls_to_zero():
    graph = graph_of(4)
    set_links(graph, 3, {0: 25, 1: 30, 2: 40})
    set_links(graph, 3, {1: 22, 2: 0})  # the link to 0 goes, the one to 2 drops to nothing
    assert graph.shared(3) == {1: 22}
    assert graph.shared(0) == {}
    assert graph.shared(1) == {3: 22}
    assert graph.shared(2) == {}
    assert graph.neighbours(2) == []


def test_a_link_of_a_keyframe_to_itself_is_ignored():
    graph = graph_of(2)
    set_links(graph, 1, {1: 50, 0: 21})
    assert graph.shared(1) == {0: 21}


def test_shared_returns_a_copy_that_does_not_change_the_graph():
    graph = graph_of(2)
    set_links(graph, 1, {0: 21})
    graph.shared(1)[0] = 99
    assert graph.shared(1) == {0: 21}


# --- spanning tree --------------------------------------------------------------------


def test_a_keyframe_parent_is_its_strongest_link_when_first_linked():
    graph = graph_of(4)
    set_links(graph, 1, {0: 30})
    set_links(graph, 2, {0: 30, 1: 60})
    set_links(graph, 3, {0: 40, 1: 40, 2: 10})  # tie: the lower id
    assert graph.parent == {0: None, 1: 0, 2: 1, 3: 0}
    assert graph.children == {0: {1, 3}, 1: {2}, 2: set(), 3: set()}


def test_a_parent_is_kept_when_later_links_make_another_keyframe_stronger():
    graph = graph_of(3)
    set_links(graph, 1, {0: 30})
    set_links(graph, 2, {0: 50, 1: 20})
    set_links(graph, 2, {0: 5, 1: 90})
    assert graph.parent[2] == 0


def test_the_root_is_the_first_keyframe_and_never_gets_a_parent():
    graph = graph_of(3)
    set_links(graph, 1, {0: 30})
    set_links(graph, 2, {0: 10, 1: 20})
    set_links(graph, 0, {1: 30, 2: 80})
    assert graph.root == 0
    assert graph.parent[0] is None
    assert graph.parent[1] == 0 and graph.parent[2] == 1


def test_a_keyframe_not_linked_yet_has_no_parent():
    graph = graph_of(3)
    set_links(graph, 1, {0: 30})
    set_links(graph, 2, {})
    assert graph.parent[2] is None and 2 not in graph.children[0] and 2 not in graph.children[1]


def test_a_keyframe_first_linked_after_a_later_keyframe_chose_it_as_parent_still_reaches_the_root():
    graph = graph_of(3)
    set_links(graph, 0, {})
    set_links(graph, 1, {})  # shares nothing yet: no parent
    set_links(graph, 2, {1: 30, 0: 5})  # 2 takes 1 as parent
    set_links(graph, 1, {2: 30})  # 1 is first linked now, and only to 2
    assert reaches_root(graph, 1) and reaches_root(graph, 2)


# --- removing keyframes ---------------------------------------------------------------


def test_removing_a_keyframe_drops_its_links_from_the_others():
    graph = graph_of(4)
    set_links(graph, 1, {0: 30})
    set_links(graph, 2, {0: 25, 1: 40})
    set_links(graph, 3, {1: 22, 2: 35})
    graph.remove_keyframe(1)
    assert 1 not in graph
    assert 1 not in graph.parent and 1 not in graph.children
    assert graph.shared(0) == {2: 25}
    assert graph.shared(2) == {0: 25, 3: 35}
    assert graph.shared(3) == {2: 35}
    assert all(1 not in children for children in graph.children.values())


def test_removing_a_keyframe_reattaches_each_child_to_the_strongest_linked_of_the_old_parent_and_reattached_siblings():
    graph = graph_of(6)
    set_links(graph, 1, {0: 30})
    # Children of 1: 2, 3, 4, 5 (each linked most strongly to 1).
    set_links(graph, 2, {1: 100, 0: 20})
    set_links(graph, 3, {1: 100, 2: 50, 0: 10})
    set_links(graph, 4, {1: 100, 3: 70, 0: 40})
    set_links(graph, 5, {1: 100})  # nothing left once 1 goes: falls back to the old parent
    assert graph.children[1] == {2, 3, 4, 5}
    graph.remove_keyframe(1)
    # Candidates {0}: 4 (40) beats 2 (20) and 3 (10) -> 4 under 0.
    # Candidates {0, 4}: 3 to 4 (70) -> 3 under 4.
    # Candidates {0, 4, 3}: 2 to 3 (50) -> 2 under 3.
    assert graph.parent[4] == 0
    assert graph.parent[3] == 4
    assert graph.parent[2] == 3
    assert graph.parent[5] == 0
    assert graph.children[0] == {4, 5}
    assert graph.children[4] == {3} and graph.children[3] == {2}
    assert_tree(graph)


def test_a_tie_between_reattachments_goes_to_the_lower_child_then_the_lower_candidate():
    graph = graph_of(5)
    set_links(graph, 1, {0: 30})
    set_links(graph, 2, {1: 30, 0: 25})
    set_links(graph, 3, {1: 80, 0: 25, 2: 25})
    graph.remove_keyframe(1)
    # 2 and 3 tie at 25 to 0: 2 first; then 3 ties between 0 and 2: the lower id, 0.
    assert graph.parent[2] == 0
    assert graph.parent[3] == 0


def test_removing_a_leaf_changes_no_other_parent():
    graph = graph_of(4)
    set_links(graph, 1, {0: 30})
    set_links(graph, 2, {1: 30})
    set_links(graph, 3, {2: 30})
    graph.remove_keyframe(3)
    assert graph.parent == {0: None, 1: 0, 2: 1}
    assert graph.children[2] == set()


@pytest.mark.parametrize("seed", range(5))
def test_after_many_removals_every_keyframe_still_reaches_the_root(seed):
    rng = np.random.default_rng(seed)
    n = 30
    graph = graph_of(n)
    for keyframe in range(1, n):
        others = rng.choice(keyframe, size=min(keyframe, 4), replace=False)
        set_links(graph, keyframe, {int(o): int(rng.integers(1, 60)) for o in others})
    assert_tree(graph)
    for victim in rng.permutation(np.arange(1, n))[:20].tolist():
        graph.remove_keyframe(victim)
        assert victim not in graph
        assert_tree(graph)
    assert len(graph.parent) == n - 20
