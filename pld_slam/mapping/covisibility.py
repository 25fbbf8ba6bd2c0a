"""The covisibility graph of the keyframes and its spanning tree.

Two keyframes are linked by the number of landmarks (points and lines) both observe. The
paper (section "Local map update") makes an edge of a link of at least 20 shared
landmarks (``mapping.covisibility_min_shared``). As ORB-SLAM2, a keyframe whose links are
all weaker keeps its strongest one as an edge, so that no keyframe is left without
neighbours after a fast turn; every link, however weak, stays known (`shared`), because
local BA needs every keyframe that sees its landmarks, not only the neighbours.

The spanning tree (ORB-SLAM2) connects every keyframe to the keyframe it shared the most
landmarks with when it was first linked, among those already in the tree: its parent. (A
keyframe that shared nothing when inserted, after a fast turn, is linked later; taking
its strongest link then, whatever it is, could pick a keyframe that had since taken it
as parent: a cycle off the tree.) Loop closure optimises poses along
it. When a keyframe is culled, its children are re-attached one by one, each to the
strongest-linked keyframe among its old parent and the children already re-attached,
and otherwise to its old parent.

Ties in weight go to the lower keyframe id, so the graph is the same on every run.
"""

from collections.abc import Iterable


class CovisibilityGraph:
    """Weighted links between keyframes (by id) and the spanning tree (module docstring)."""

    def __init__(self, min_shared: int) -> None:
        self.min_shared = min_shared
        self._shared: dict[int, dict[int, int]] = {}
        self.parent: dict[int, int | None] = {}
        """Spanning-tree parent of each keyframe (None for the root and keyframes not linked yet)."""
        self.children: dict[int, set[int]] = {}

    def __contains__(self, keyframe: int) -> bool:
        return keyframe in self._shared

    def add_keyframe(self, keyframe: int) -> None:
        """A keyframe without links (its observations link it, `change_shared`)."""
        self._shared[keyframe] = {}
        self.parent[keyframe] = None
        self.children[keyframe] = set()

    def attach_to_tree(self, keyframe: int) -> None:
        """Give ``keyframe``, if it has no parent yet and is not the root, its strongest link to
        a keyframe that reaches the root as its parent (module docstring); else change nothing."""
        if self.parent[keyframe] is not None or keyframe == self.root:
            return
        links = self._shared[keyframe]
        rooted = {other: count for other, count in links.items() if self.reaches_root(other)}
        if rooted:
            self._attach(keyframe, _strongest(rooted))

    def change_shared(self, keyframe: int, others: Iterable[int], delta: int) -> None:
        """Add ``delta`` to the landmarks ``keyframe`` shares with each of ``others`` (both directions).

        A link that falls to zero is dropped. The spanning tree is not changed.
        """
        links = self._shared[keyframe]
        for other in others:
            if other == keyframe:
                continue
            count = links.get(other, 0) + delta
            if count > 0:
                links[other] = self._shared[other][keyframe] = count
            else:
                links.pop(other, None)
                self._shared[other].pop(keyframe, None)

    def unlink_all(self, keyframes: list[int]) -> None:
        """Lower by one the link of every pair of ``keyframes``: a landmark they all observed is gone."""
        for index, keyframe in enumerate(keyframes):
            self.change_shared(keyframe, keyframes[index + 1 :], -1)

    def reaches_root(self, keyframe: int) -> bool:
        """Whether following the spanning-tree parents from ``keyframe`` ends at the root."""
        while self.parent[keyframe] is not None:
            keyframe = self.parent[keyframe]
        return keyframe == self.root

    @property
    def root(self) -> int:
        """The first keyframe."""
        return min(self._shared)

    def shared(self, keyframe: int) -> dict[int, int]:
        """Every keyframe linked to ``keyframe`` and the landmarks both see (a copy)."""
        return dict(self._shared[keyframe])

    def neighbours(self, keyframe: int, limit: int | None = None) -> list[int]:
        """The keyframes joined to ``keyframe`` by an edge, strongest first (at most ``limit``).

        An edge is a link of at least ``min_shared`` landmarks; with none, the strongest
        link (module docstring).
        """
        links = self._shared[keyframe]
        ordered = sorted(links, key=lambda other: (-links[other], other))
        edges = [other for other in ordered if links[other] >= self.min_shared] or ordered[:1]
        return edges if limit is None else edges[:limit]

    def remove_keyframe(self, keyframe: int) -> None:
        """Drop a keyframe and its links; re-attach its children (module docstring)."""
        parent = self.parent.pop(keyframe)
        orphans = self.children.pop(keyframe)
        if parent is not None:
            self.children[parent].discard(keyframe)
        for other in self._shared.pop(keyframe):
            self._shared[other].pop(keyframe, None)
        self._reattach(orphans, parent)

    def _attach(self, keyframe: int, parent: int | None) -> None:
        self.parent[keyframe] = parent
        if parent is not None:
            self.children[parent].add(keyframe)

    def _reattach(self, orphans: set[int], old_parent: int | None) -> None:
        """Give each orphan the strongest-linked candidate parent, growing the candidates as they attach."""
        candidates = {old_parent} if old_parent is not None else set()
        orphans = set(orphans)
        while orphans:
            best = None
            for child in sorted(orphans):
                for candidate, count in self._shared[child].items():
                    if candidate in candidates and (best is None or (count, -child, -candidate) > best[0]):
                        best = ((count, -child, -candidate), child, candidate)
            if best is None:
                break
            _, child, candidate = best
            self._attach(child, candidate)
            orphans.discard(child)
            candidates.add(child)
        for child in sorted(orphans):
            self._attach(child, old_parent)


def _strongest(shared: dict[int, int]) -> int:
    """The keyframe of the strongest link (ties: the lower id)."""
    return min(shared, key=lambda other: (-shared[other], other))
