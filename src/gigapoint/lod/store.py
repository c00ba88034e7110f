"""The gigapoint octree: reader (OctreeCloud, ``read_gigapoint``), node arena and LOD selection.

The folder's layout (file names, metadata, arrays) is octree_dir.py's; writer.py writes it;
every array is memory-mapped when read.

Rendering never transcodes: selected nodes are copied slot by slot into an Arena (one
preallocated set of point buffers cut into fixed-size chunks, SimLOD-style) and the arena
is drawn by the same kernel as any PointCloud, each chunk a batch.
"""

from __future__ import annotations

import contextlib
import json
import math
from collections import OrderedDict
from pathlib import Path

import numpy as np
from numba import njit

from ..core.attributes import Attributes, Packed, packed_range, stored
from ..core.chunk import attribute_name_problem
from ..core.cloud import MAX_ABS_COORDINATE, at_scale
from ..core.compact import centre_half, point_words, rgba32, stream_subset, stream_words
from ..core.layout import BATCH_DTYPE, PACK_DTYPE
from ..core.quantize import dequantize
from ..core.renderable import DrawList, MultiViewDrawList, check_classified, check_point_index, held_points
from ..core.selection import Selection, View, batch_matrices, box_in_view, precision_for, visible_and_size
from ..errors import InputError, is_whole_number
from ..io.filters import PointFilter
from ..render.splats import finest_spacing, union_gain
from .class_counts import kept_by_class
from .keys import key_cube, morton_position
from .octree_dir import FORMAT_NAME, FORMAT_VERSION_WORDS, FORMAT_VERSIONS, POINT_ARRAYS, OctreeDir

ARENA_CHUNK = 4096  # points per arena slot (a node spans ceil(count / ARENA_CHUNK) slots)
# selections a frame with a load filter (hidden classes, a read filter) makes at most: each weighs
# the nodes the last one loaded (a progressive octree: the chunks it filtered) by their kept
# points, the others by the share their nearest loaded ancestor kept (``kept_shares``); the last
# weighs those whole, so what it loads keeps within the budget whatever they keep
KEPT_ROUNDS = 8
#: The least share of its points a node not yet loaded is taken to keep (``kept_shares``): a
#: round loads at most 1 / MIN_KEPT_SHARE times the budget it has left, however little the
#: nodes above kept (a subtree of hidden points is not read whole for a guess of nothing kept)
MIN_KEPT_SHARE = 0.25
#: Node boxes are widened by this share of the octree's cube before they are tested against a
#: region: writers choose cubes before rounding positions to their grid, so a point may lie a
#: step outside its box
BOX_SLACK = 1e-3


# --------------------------------------------------------------------------- selection kernels


@njit(cache=True)
def _box_test(rows, bmin, size, width, height, near, far):
    """(in the frustum, projected size in px, distance of its projection from the image centre
    as a fraction of the half diagonal) of a box; size inf and distance 0 when it crosses the near plane."""
    visible, in_front, xmin, xmax, ymin, ymax = box_in_view(rows, bmin[0], bmin[1], bmin[2], size[0], size[1], size[2], width, height, near, far)
    if not in_front:
        return visible, np.inf, 0.0
    cx = min(max(width * 0.5, xmin), xmax) - width * 0.5
    cy = min(max(height * 0.5, ymin), ymax) - height * 0.5
    return visible, max(xmax - xmin, ymax - ymin), np.sqrt(cx * cx + cy * cy) / (0.5 * np.sqrt(width * width + height * height))


@njit(inline="always")
def _heap_place(hp, hi, n, j, p, item):
    """Put (priority ``p``, ``item``) into the hole at ``j`` of the max-heap ``hp``/``hi`` of ``n``
    entries: entries move down into the hole while their priority is lower (sift up), then up
    while a child's is higher (sift down). A push fills a hole at the end, a pop the one at 0."""
    while j > 0:
        q = (j - 1) // 2
        if hp[q] >= p:
            break
        hp[j] = hp[q]
        hi[j] = hi[q]
        j = q
    while True:
        c = 2 * j + 1
        if c >= n:
            break
        if c + 1 < n and hp[c + 1] > hp[c]:
            c += 1
        if hp[c] <= p:
            break
        hp[j] = hp[c]
        hi[j] = hi[c]
        j = c
    hp[j] = p
    hi[j] = item


@njit(cache=True)
def select_nodes(rows, box_min, box_size, counts, costs, meets, children, width, height, near, far, threshold, budget, out_ids, out_size, foveation=0.0):
    """Largest-projected-first traversal: visible nodes of ≥ threshold px (the root always, and
    the children of a node without points), within budget.

    ``costs``: what each node takes of the budget (its points drawn: ``counts``, or fewer where
    a load filter leaves some out); ``counts`` tells the nodes without points (a node whose
    points are all left out is no reason to descend below the threshold). ``meets``: whether a
    node's box meets the read filter's region; a node that does not is skipped with its subtree.

    ``foveation`` f > 0 raises the threshold away from the image centre: threshold · (1 + f·d),
    d = 0 at the centre .. 1 in the corners (the 2022 paper's 100/200/300 px is f = 2).

    ``box_min``/``box_size`` (k, 3): each node's cube clipped to the cloud's bounds (it holds
    every point of the node's subtree, without the cube's empty space).

    Returns (number of selected nodes written to out_ids/out_size, their total cost).
    """
    n = counts.shape[0]
    hp = np.empty(n, np.float64)
    hi = np.empty(n, np.int64)
    hn = 0
    vis, s, _ = _box_test(rows, box_min[0], box_size[0], width, height, near, far)
    if not vis or not meets[0]:
        return 0, 0
    hp[0] = s
    hi[0] = 0
    hn = 1
    k = 0
    total = 0
    while hn > 0:
        node = hi[0]
        size = hp[0]
        hn -= 1
        _heap_place(hp, hi, hn, 0, hp[hn], hi[hn])  # pop: the last entry fills the top's hole
        cnt = counts[node]
        if total + costs[node] > budget and k > 0:
            break
        out_ids[k] = node
        out_size[k] = size
        k += 1
        total += costs[node]
        for d in range(8):
            ch = children[node, d]
            if ch < 0 or not meets[ch]:
                continue
            vis, s, dist = _box_test(rows, box_min[ch], box_size[ch], width, height, near, far)
            # the children of a node without points, whatever their size (a COPC root may hold none)
            if not vis or (cnt > 0 and s < threshold * (1.0 + foveation * dist)):
                continue
            hn += 1
            _heap_place(hp, hi, hn, hn - 1, s, ch)  # push: into the new hole at the end
    return k, total


@njit(cache=True)
def kept_shares(kept, whole, parent):
    """Per node, the share of its points a load filter is taken to keep: ``kept[n] / whole[n]``
    (of its points filtered so far) where ``whole[n]`` > 0, else that of its nearest ancestor
    with one (classes mix much alike in a node and its children, which cover the same ground),
    else 1; at least MIN_KEPT_SHARE. ``parent``: each node's, -1 for the root (in any order)."""
    share = np.full(parent.shape[0], -1.0)
    for i in range(parent.shape[0]):
        top = i  # the nearest node from i up whose share is set or known
        while share[top] < 0 and whole[top] == 0 and parent[top] >= 0:
            top = parent[top]
        if share[top] < 0:
            share[top] = max(kept[top] / whole[top], MIN_KEPT_SHARE) if whole[top] > 0 else 1.0
        j = i
        while share[j] < 0:  # the nodes between take its share
            share[j] = share[top]
            j = parent[j]
    return share


@njit(inline="always")
def _as_sample(sampled, node, s, dist, threshold, foveation):
    """Whether a leaf draws its grid sample alone: it has one and its children, were it split,
    would be too small on screen to be drawn (half its projected size under the threshold)."""
    return sampled[node] > 0 and 0.5 * s < threshold * (1.0 + foveation * dist)


@njit(cache=True)
def select_octants(
    rows, box_min, box_size, costs, list_counts, list_costs, parent, children, width, height, near, far, threshold, budget, drawn,
    size_of, foveation, root, sampled, sample_costs, sampled_drawn,
):  # fmt: skip
    """Node selection for octrees whose inner nodes hold representatives (voxels) of the points
    below them, in one list per child octant, and whose leaves hold every point (SimLOD):
    largest projected child first, as ``select_nodes``, but a child drawn *replaces* its
    parent's voxels of that octant instead of adding to them, so nothing is drawn twice and a
    budget that covers every point draws exactly the visible leaves. ``list_counts[8 n + o]``:
    entries of node n's list o (a leaf's points are its list 0); ``drawn[n, o]`` is set for
    every list drawn and ``size_of[n]`` for every node drawn. ``sampled[n]`` > 0: a leaf whose
    first that many points are a sample of it on the grid its children would have as inner
    nodes; where such children would be too small on screen to be drawn (half its size under
    the threshold), the leaf draws the sample alone (``sampled_drawn[n]``), as a converted
    octree draws an inner node and not its children.

    What each takes of the budget (as ``select_nodes``'s ``costs``): ``costs[n]`` (node n drawn
    whole), ``list_costs[8 n + o]`` (its list o), ``sample_costs[n]`` (its sample), the entries
    they hold or fewer where hidden classes leave some out. Returns the budget the selection takes."""
    n = costs.shape[0]
    hp = np.empty(n, np.float64)
    hi = np.empty(n, np.int64)
    vis, s, dist = _box_test(rows, box_min[root], box_size[root], width, height, near, far)
    if not vis:
        return 0
    for o in range(8):
        drawn[root, o] = list_counts[root * 8 + o] > 0
    size_of[root] = s
    total = costs[root]
    if _as_sample(sampled, root, s, dist, threshold, foveation):
        sampled_drawn[root] = True
        total = sample_costs[root]
    hn = 0
    node = root
    while True:
        for d in range(8):  # the drawn node's children become candidates
            ch = children[node, d]
            if ch < 0:
                continue
            vis, s, dist = _box_test(rows, box_min[ch], box_size[ch], width, height, near, far)
            if vis and s >= threshold * (1.0 + foveation * dist):
                hn += 1
                _heap_place(hp, hi, hn, hn - 1, s, ch)
        while True:
            if hn == 0:
                return total
            node = hi[0]
            s = hp[0]
            hn -= 1
            _heap_place(hp, hi, hn, 0, hp[hn], hi[hn])
            p = parent[node]
            d = 0
            while children[p, d] != node:
                d += 1
            as_sample = False
            if sampled[node] > 0:  # its distance from the image centre, again (the heap holds sizes only)
                _, _, dist = _box_test(rows, box_min[node], box_size[node], width, height, near, far)
                as_sample = _as_sample(sampled, node, s, dist, threshold, foveation)
            cost = (sample_costs[node] if as_sample else costs[node]) - list_costs[p * 8 + d]
            if total + cost <= budget:
                break
        drawn[p, d] = False
        for o in range(8):
            drawn[node, o] = list_counts[node * 8 + o] > 0
        size_of[node] = s
        sampled_drawn[node] = as_sample
        total += cost


@njit(cache=True)
def list_chunks(first_chunk, chunk_next, lists, out, owner, max_chunks):
    """The chunks of every list in ``lists`` (and the index of its list), its first
    ``max_chunks[j]`` at most; returns how many."""
    k = 0
    for j in range(lists.shape[0]):
        c = first_chunk[lists[j]]
        left = max_chunks[j]
        while c >= 0 and left > 0:
            out[k] = c
            owner[k] = j
            k += 1
            left -= 1
            c = chunk_next[c]
    return k


@njit(cache=True)
def _copy_slots(src, first, count, slots, chunk, dst):
    """A node's points src[first:first+count] into arena slots (chunk points each) of dst."""
    for j in range(slots.shape[0]):
        s0 = first + j * chunk
        d0 = slots[j] * chunk
        for i in range(min(chunk, count - j * chunk)):
            dst[d0 + i] = src[s0 + i]


# --------------------------------------------------------------------------- arena


class Arena:
    """Preallocated point buffers cut into ``ARENA_CHUNK``-point slots, with an LRU of resident nodes.

    The octree's PointBuffers (core/renderable.py): ``low``, ``med``, ``high``, ``color``,
    ``attributes`` and ``batches`` (one BATCH_DTYPE record per slot), rewritten in place as
    nodes come and go, so it counts its writes in ``version`` and ``batch_version``.

    ``ext_bits`` (an int): the compact layout instead (core/compact.py), nodes held as a
    format-2 octree stores them (``CompactOctree.node_payload``): ``med``/``high`` None, a
    PACK_DTYPE record per slot (``packing``) and ``ext``, where slot s's extension stream has a
    fixed room of ``stream_words(ext_bits, ARENA_CHUNK)`` u64 words from word s · room (the
    octree's widest node fits; a node's slot j is words 64 t · j.. of its stream, which start
    on a word since 4096 t bits are whole words). Rooms never move, so a GPU page of slots has
    a fixed range of ``ext`` too. ``color_dtype``: u16 for RGB565 colours.

    ``attribute_ranges`` ({name: (min, max)} of an integer attribute over the whole octree, known
    from a format-2 octree's per-node frames of reference): that attribute is held as ``value -
    min`` in the narrowest unsigned dtype of its range (core/attributes.py: ``attributes[name]``
    reads the original values), nodes' values written through ``Packed.encode``.
    """

    def __init__(
        self, capacity_points: int, name: str, bounds, attribute_dtypes: dict | None = None, ext_bits: int | None = None,
        color_dtype=np.uint32, attribute_ranges: dict | None = None,
    ):  # fmt: skip
        n_slots = max(1, -(-int(capacity_points) // ARENA_CHUNK))
        size = n_slots * ARENA_CHUNK
        self.low = np.zeros(size, np.uint32)
        if ext_bits is None:
            self.med = np.zeros(size, np.uint32)
            self.high = np.zeros(size, np.uint32)
        else:
            self.med = self.high = None
            self.room = int(stream_words(np.int64(ext_bits), np.int64(ARENA_CHUNK)))
            self.ext = np.zeros(n_slots * self.room, np.uint64)
            self.packing = np.zeros(n_slots, PACK_DTYPE)
            self.packing["ext_first"] = np.arange(n_slots, dtype=np.uint64) * np.uint64(self.room)
        self.color = np.zeros(size, color_dtype)
        self.attributes = Attributes()
        for a, dt in (attribute_dtypes or {}).items():
            known = (attribute_ranges or {}).get(a)
            packed = packed_range(*known, dt, size) if known is not None else None
            self.attributes.hold(a, packed if packed is not None else np.zeros(size, dt))
        self.batches = np.zeros(n_slots, BATCH_DTYPE)
        self.batches["first"] = np.arange(n_slots, dtype=np.uint64) * ARENA_CHUNK
        self.resident: OrderedDict[int, np.ndarray] = OrderedDict()
        self.free = list(range(n_slots - 1, -1, -1))
        self.name = name
        self.bounds = bounds
        self.source_scale = None  # the octree's source grid (a LAS file's scale), which point_info rounds to
        self.loads = 0  # nodes copied in since creation, or in an arena it took over (cache misses)
        self.keep: PointFilter | None = None  # what the resident nodes were loaded through (``show``)
        # per node: the points it kept when last loaded through ``keep`` (-1: not loaded since),
        # known after the LRU drops it, so that a selection weighs it by them (``kept_counts``)
        self.kept = np.empty(0, np.int64)
        self.resident_changes = 0  # bumped whenever a node is made resident or dropped (``kept_counts`` reuses its answer until then)
        self._kept_counts: tuple = (None, None)  # (what ``kept_counts`` last answered for, its answer)
        # Bumped on every write; per slot, the version that last filled it (GPU backends re-upload those slots)
        self.version = 0
        self.batch_version = np.zeros(n_slots, np.int64)

    @property
    def n_slots(self) -> int:
        return len(self.batches)

    @property
    def n_points(self) -> int:
        return len(self.low)

    @property
    def nbytes(self) -> int:
        """Bytes of its point buffers (positions, colours, attributes; not the slot records)."""
        arrays = [self.low, self.color]
        arrays += [self.med, self.high] if self.med is not None else [self.ext]
        return sum(a.nbytes for a in arrays) + self.attributes.nbytes

    def point_info(self, index: int) -> dict | None:
        """Position (rounded to ``source_scale``, the octree's source grid, where it has one),
        color, level and attributes of the point in slot position ``index``; None for -1 (no point)."""
        check_point_index(index, self.n_points, self.name)
        if index == -1:
            return None
        slot = int(np.searchsorted(self.batches["first"], np.uint64(index), side="right") - 1)
        rec = self.batches[slot]
        low, med, high = point_words(self, slot, index, index + 1)
        half = centre_half(None if self.med is not None else self.packing["code"][slot])  # (a grid-aligned node's words: its grid values)
        pos = dequantize(low, med, high, rec["bbox_min"], rec["bbox_max"], 30, half)[0]
        rgba = rgba32(self.color[index : index + 1]).view(np.uint8).tolist()
        info = {"position": at_scale(pos, self.source_scale), "rgba": rgba, "level": int(rec["level"]), "source": "octree"}
        for a in self.attributes:
            info[a] = self.attributes.at(a, [index])[0].item()
        return info

    def resident_classification(self) -> np.ndarray | None:
        """The ``classification`` of the points its resident nodes hold (the viewer lists the
        classes seen so far where an octree's metadata names none); None without the attribute."""
        if "classification" not in self.attributes:
            return None
        slots = np.concatenate([np.zeros(0, np.int64), *self.resident.values()])
        return self.attributes.at("classification", held_points(self.batches[slots]))

    def show(self, keep: PointFilter | None) -> None:
        """Nodes loaded from now on keep only the points ``keep`` keeps (``OctreeCloud.load_filter``:
        its read filter, hidden classes; None: all); a change drops every resident node and
        what each node kept, so frames load them again, filtered."""
        if keep == self.keep:
            return
        for slots in self.resident.values():
            self.free.extend(slots.tolist())
        self.resident.clear()
        self.kept[:] = -1
        self.resident_changes += 1
        self.keep = keep

    def kept_counts(self, counts: np.ndarray, keep: PointFilter | None, parent: np.ndarray | None) -> np.ndarray:
        """The nodes' ``counts`` as a selection through the load filter ``keep`` should weigh
        them: a node loaded through it counts the points it kept (resident still or dropped
        since: ``kept``); the others, given ``parent`` (each node's, -1 for the root), their
        counts times the share their nearest loaded ancestor kept (``kept_shares``), else their
        whole counts (what they keep is known once loaded: no more than that). The same array
        while no node was made resident or dropped since (a frame selects two times or more,
        each a pass over every node)."""
        if keep is None or keep != self.keep:
            return counts
        asked = (self.resident_changes, counts, parent)  # (an octree whose hierarchy grew asks with new counts and parents)
        last, answer = self._kept_counts
        if last is not None and last[0] == asked[0] and last[1] is counts and last[2] is parent:
            return answer
        nodes = np.flatnonzero(self.kept[: len(counts)] >= 0)
        if not len(nodes):
            return counts
        kept = self.kept[nodes]
        out = counts.copy()
        if parent is not None:
            kept_of, whole = np.zeros_like(counts), np.zeros_like(counts)
            kept_of[nodes], whole[nodes] = kept, counts[nodes]
            out = np.ceil(counts * kept_shares(kept_of, whole, parent)).astype(np.int64)
        out[nodes] = kept
        self._kept_counts = (asked, out)
        return out

    def _load(self, nd: int, cloud: OctreeCloud, slots: np.ndarray, count: int) -> int:
        """Node ``nd``'s points into ``slots``, in the arena's layout, those ``keep`` keeps;
        returns how many it loaded."""
        if self.med is None:  # the compact layout: the node's words as stored (a format-2 octree)
            arrays, attrs = cloud.node_payload(nd)
            first, words = 0, ["low"]
        else:
            arrays, attrs, first = cloud.node_arrays(nd)  # a Potree node is read and decoded here
            words = ["low", "med", "high"]
        colors = "color" if cloud.filtered_colors else "rgba"
        if self.keep is not None:  # the node's points the filter keeps (inner nodes' too: real points, with their class)
            node = slice(first, first + count)
            xyz = self._positions(cloud, nd, arrays, node) if self.keep.needs_positions else None
            classification = attrs["classification"][node] if "classification" in attrs else None
            kept = np.flatnonzero(self.keep.keeps(xyz, classification, cloud.name))
            filtered = {k: np.asarray(arrays[k][node])[kept] for k in [*words, colors]}
            if self.med is None:
                filtered.update(ext=stream_subset(arrays["ext"], int(arrays["code"]), kept), code=arrays["code"], bits=arrays["bits"])
            arrays, attrs = filtered, {a: np.asarray(attrs[a][node])[kept] for a in self.attributes}
            first, count = 0, len(kept)
        if self.med is None:
            t = arrays["bits"]
            for j, s in enumerate(slots.tolist()):
                w = -(-min(ARENA_CHUNK, count - j * ARENA_CHUNK) * t // 64)  # the room's spare word left: only masked bits are read there
                if w > 0:
                    self.ext[s * self.room : s * self.room + w] = arrays["ext"][64 * t * j : 64 * t * j + w]
            self.packing["code"][slots] = arrays["code"]
        held_words = [self.low] if self.med is None else [self.low, self.med, self.high]
        pairs = [(arrays[w], into) for w, into in zip(words, held_words)]
        pairs.append((arrays[colors], self.color))
        for a in self.attributes:
            held = self.attributes.held(a)
            if not isinstance(held, Packed):
                pairs.append((attrs[a], held))
            elif held.stored is not None:  # packed only for a compact payload: the node's own values (first = 0)
                pairs.append((held.encode(attrs[a][:count]), held.stored))
        for a, b in pairs:
            _copy_slots(a, first, count, slots, ARENA_CHUNK, b)
        return count

    def _positions(self, cloud: OctreeCloud, nd: int, arrays: dict, node: slice) -> np.ndarray:
        """The positions of node ``nd``'s points ``node`` of ``arrays`` (as ``_load`` read them:
        a compact payload's tails decoded first), against its box (the tight one a Potree, COPC
        or EPT node's record holds once read)."""
        if self.med is None:
            med, high = cloud.payload_tails(arrays)
        else:
            med, high = arrays["med"][node], arrays["high"][node]
        rec = cloud.nodes[nd]
        low = np.asarray(arrays["low"][node])
        return dequantize(low, np.asarray(med), np.asarray(high), rec["bbox_min"], rec["bbox_max"], 30, cloud.node_half(nd))

    def renumber(self, new_index: np.ndarray, n_nodes: int) -> None:
        """Follow an octree whose nodes were numbered again (a hierarchy that grew: node i is
        now node ``new_index[i]`` of ``n_nodes``): its resident nodes and what each kept."""
        resident = list(self.resident.items())
        self.resident.clear()
        self.resident.update((int(new_index[i]), slots) for i, slots in resident)
        kept = np.full(n_nodes, -1, np.int64)
        kept[new_index[: len(self.kept)]] = self.kept
        self.kept = kept

    def take_over(self, old: Arena) -> None:
        """Hold what ``old`` held, an arena of the same layout and no more slots that this one
        replaces (too small for a frame): its slots as they are (a slot's place in the buffers
        depends on its number alone), its resident nodes, the filter they were loaded through,
        what each node kept and its count of loads. The next frame then neither loads its nodes
        again nor weighs them by estimates (issue #18)."""
        n = old.n_slots
        held = [(old.low, self.low), (old.color, self.color)]
        if old.med is not None:
            held += [(old.med, self.med), (old.high, self.high)]
        else:
            held += [(old.ext, self.ext), (old.packing, self.packing)]
        held += [(stored(old.attributes.held(a)), stored(self.attributes.held(a))) for a in old.attributes]
        for had, has in held:
            if had is not None:  # (None: a constant attribute, nothing stored)
                has[: len(had)] = had
        self.batches[:n] = old.batches
        self.batch_version[:n] = old.batch_version
        self.version = old.version
        self.resident = OrderedDict(old.resident)
        self.free = list(range(self.n_slots - 1, n - 1, -1)) + old.free
        self.keep, self.kept, self.loads = old.keep, old.kept.copy(), old.loads
        self.resident_changes = old.resident_changes + 1

    def ensure(self, nodes: np.ndarray, cloud: OctreeCloud) -> bool:
        """Make every node in ``nodes`` resident; False when they cannot all fit."""
        if len(self.kept) < len(cloud.counts):  # (its first nodes: a count for each of the octree's)
            self.kept = np.full(len(cloud.counts), -1, np.int64)
        need = 0
        wanted = set(nodes.tolist())
        for nd in nodes.tolist():
            if nd in self.resident:
                self.resident.move_to_end(nd)
            else:
                need += -(-int(cloud.nodes["count"][nd]) // ARENA_CHUNK)
        if need > len(self.free):
            for nd in list(self.resident):
                if len(self.free) >= need:
                    break
                if nd not in wanted:
                    self.free.extend(self.resident.pop(nd).tolist())
                    self.resident_changes += 1
        if need > len(self.free):
            return False
        for nd in nodes.tolist():
            if nd in self.resident:
                continue
            rec = cloud.nodes[nd]
            count = int(rec["count"])
            k = -(-count // ARENA_CHUNK)
            slots = np.array([self.free.pop() for _ in range(k)], np.int64)
            loaded = self._load(nd, cloud, slots, count)
            # 0: found damaged as it was read (voxel_octree.py), its slots left empty
            count = min(loaded, int(cloud.nodes["count"][nd]))
            used = max(1, -(-count // ARENA_CHUNK))  # slots left over by hidden classes freed again
            self.free.extend(slots[used:].tolist())
            slots, k = slots[:used], used
            b = self.batches[slots]
            b["count"] = np.clip(count - np.arange(k) * ARENA_CHUNK, 0, ARENA_CHUNK)
            b["level"] = rec["level"]
            b["bbox_min"] = rec["bbox_min"]
            b["bbox_max"] = rec["bbox_max"]
            self.batches[slots] = b
            self.resident[nd] = slots
            self.kept[nd] = count
            self.resident_changes += 1
            self.loads += 1
            self.version += 1
            self.batch_version[slots] = self.version
        return True


# --------------------------------------------------------------------------- reader


class OctreeCloud:
    """A converted LOD octree: a Renderable (core/renderable.py) whose ``prepare`` selects nodes
    (largest projected first, within the point budget) and draws them from its arena."""

    load_progress = 1.0  # converted whole
    read_filter: PointFilter | None = None  # only the points it keeps are drawn (``read_only``)
    class_counts: np.ndarray | None = None  # per-node class counts where its files hold them (class_counts.py)

    def __init__(
        self, name: str, meta: dict, nodes: np.ndarray, keys: np.ndarray, arrays: dict, attributes: dict, path: Path | None = None
    ):
        self.name = name
        self.meta = meta
        self.nodes = nodes
        self.keys = np.asarray(keys, np.uint64)
        self.arrays = arrays
        self.attributes = attributes
        self.path = path
        self.filtered_colors = True
        self.arena: Arena | None = None
        self._union_gain: np.ndarray | None = None  # adaptive sizes' per-node facts (prepare), made on first use
        self._node_spacing: np.ndarray | None = None
        self.counts = nodes["count"].astype(np.int64)  # node counts never change: widened once, not per frame
        self._meets: np.ndarray | None = None  # which nodes' boxes meet the read filter (``meeting_read_filter``), made on first use
        self._kept_bounds: tuple = (None, None)  # (a load filter, what ``kept_bounds`` answered for it)
        self.morton_position = morton_position(self.keys)  # frames draw node after node in this order
        self.cube_min, self.cube_edge = key_cube(self.keys, meta["cube_min"], float(meta["cube_edge"]))
        lo, hi = self.stored_bounds()
        self.box_min = np.clip(self.cube_min, lo, hi)
        self.box_size = np.clip(self.cube_min + self.cube_edge[:, None], lo, hi) - self.box_min
        self.children = np.full((len(self.keys), 8), -1, np.int64)
        self.parent = np.full(len(self.keys), -1, np.int64)  # (-1: the root)
        if len(self.keys) > 1:
            kid = np.arange(1, len(self.keys))
            parents = np.searchsorted(self.keys, self.keys[1:] >> np.uint64(3))
            if np.any(parents >= len(self.keys)) or np.any(
                self.keys[np.minimum(parents, len(self.keys) - 1)] != self.keys[1:] >> np.uint64(3)
            ):
                raise InputError(f"{path or name}: octree hierarchy is broken (a node without its parent)")
            self.children[parents, (self.keys[1:] & np.uint64(7)).astype(np.int64)] = kid
            self.parent[kid] = parents
        if len(self.keys) == 0 or self.keys[0] != 1:
            raise InputError(f"{path or name}: octree has no root node")

    # -- PointCloud-like facts
    @property
    def n_points(self) -> int:
        return int(self.meta["points"])

    def __len__(self) -> int:
        return self.n_points

    @property
    def batches(self) -> np.ndarray:
        return self.nodes

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Its points' bounds; with a read filter, cut to where the points it keeps can be
        (``PointFilter.clipped_bounds``: what a view frames, as a filtered cloud's bounds do)."""
        lo, hi = self.stored_bounds()
        return (lo, hi) if self.read_filter is None else self.read_filter.clipped_bounds(lo, hi)

    def stored_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The bounds of all its points (its metadata's), which its nodes' boxes are cut to."""
        b = self.meta["bounds"]
        return np.array(b["min"], np.float64), np.array(b["max"], np.float64)

    @property
    def attribute_names(self) -> list[str]:
        """The point attributes its nodes carry (those of an octree read node by node are named
        by its metadata, before any node is read)."""
        return sorted(self.attributes)

    @property
    def levels(self) -> np.ndarray:
        return self.nodes["level"]

    def __repr__(self) -> str:
        lo, hi = (at_scale(b, self.meta.get("scale")) for b in self.bounds)  # at the source's grid, as PointCloud's
        return f"OctreeCloud({self.name!r}, {self.n_points:,} points, {len(self.nodes):,} node{'' if len(self.nodes) == 1 else 's'}, depth {int(self.levels.max())}, bounds {lo} .. {hi})"

    def node_arrays(self, index: int) -> tuple[dict, dict, int]:
        """(point arrays ``low``, ``med``, ``high``, ``color``, ``rgba``; attribute arrays; where node
        ``index``'s points start in them). Here: the memory-mapped files (only the pages a node's
        slice touches are read); a Potree cloud reads and decodes the node instead."""
        return self.arrays, self.attributes, int(self.nodes["first"][index])

    def node_half(self, index: int) -> np.ndarray:
        """``dequantize``'s half for node ``index``'s 30-bit words: 0.5, floor-quantized words (a
        format-2 octree's grid-aligned nodes take 0: compact_octree.CompactOctree)."""
        return centre_half(None)

    def node_points(self, index: int) -> dict:
        """Decoded float64 positions (30-bit) and colors of one node (for tests and tools)."""
        arrays, attrs, first = self.node_arrays(index)
        rec = self.nodes[index]
        s = slice(first, first + int(rec["count"]))
        xyz = dequantize(arrays["low"][s], arrays["med"][s], arrays["high"][s], rec["bbox_min"], rec["bbox_max"], 30, self.node_half(index))
        out = {"xyz": xyz, "color": np.asarray(arrays["color"][s]), "rgba": np.asarray(arrays["rgba"][s])}
        for a, v in attrs.items():
            out[a] = np.asarray(v[s])
        return out

    # -- read filter
    def read_only(self, keep: PointFilter, label: str) -> None:
        """Draw only the points ``keep`` keeps (gp.open's ``classes=``, ``clip=``, ...), level of
        detail: frames skip the nodes whose boxes do not meet it and load the others' points
        through it (``load_filter``), their kept points weighing on the budget. Nothing is read
        here; a filter naming classes of an octree (``label`` in messages) without
        classification is a one-line InputError."""
        if (keep.classes or keep.drop_classes) and "classification" not in self.attribute_names:
            raise InputError(f"{label}: holds no classification, which the filter ({keep.describe()}) needs")
        self.read_filter = keep
        self._meets = None
        if self.arena is not None:
            self.arena.show(None)  # (its nodes were loaded unfiltered: dropped)

    def load_filter(self, hidden: tuple[int, ...]) -> PointFilter | None:
        """What its nodes are loaded through: its read filter, less the LAS classes ``hidden``
        (the settings' ``hidden_classes``); None: every point."""
        if not hidden:
            return self.read_filter
        return (self.read_filter or PointFilter()).dropping(hidden)

    def boxes_meeting(self, meets, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Which of the node boxes lo..hi ((k, 3)), widened by ``BOX_SLACK`` of its cube, meet a
        region (``meets(lo, hi)``: a PointFilter's ``meets``)."""
        pad = BOX_SLACK * float(self.meta["cube_edge"])
        return meets(lo - pad, hi + pad)

    def meeting_read_filter(self) -> np.ndarray:
        """Which nodes' boxes (their subtrees') meet the read filter; all without one. Made once
        a hierarchy (a COPC/EPT octree's grows as pages are read: ``__init__`` again)."""
        if self._meets is None:
            keep = self.read_filter
            self._meets = np.ones(len(self.keys), bool) if keep is None else self.boxes_meeting(keep.meets, self.box_min, self.box_min + self.box_size)
        return self._meets

    # -- Renderable (core/renderable.py)
    def select_nodes(self, view: View, settings, estimated: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
        """(node indices, projected cube sizes, point total) chosen for a view, of the nodes
        meeting the read filter; through a load filter (``load_filter``), the nodes loaded
        through it count the points they kept, the others (``estimated``) the share their
        nearest loaded ancestor kept or (not ``estimated``) all theirs (``Arena.kept_counts``)."""
        out_ids = np.empty(len(self.keys), np.int64)
        out_size = np.empty(len(self.keys), np.float64)
        keep = self.load_filter(settings.hidden_classes)
        most, likely = self.kept_bounds(keep)
        if self.arena is None or self.knows_kept(keep):
            costs = likely  # (nothing loaded yet; or every node's kept points known from the class counts)
        else:
            # the nodes loaded count what they kept; the others' likely points times the share of
            # them their nearest loaded ancestor kept, or (not ``estimated``) the most they keep
            costs = self.arena.kept_counts(likely, keep, self.parent) if estimated else self.arena.kept_counts(most, keep, None)
            if estimated and likely is not most:  # (a share above 1 where the box's share guessed low: never past the most)
                costs = np.minimum(costs, most)
        k, total = select_nodes(
            view.rows, self.box_min, self.box_size, self.counts, costs, self.meeting_read_filter(), self.children, float(view.width), float(view.height),
            float(view.near), float(view.far), float(settings.lod_threshold_px), int(settings.point_budget), out_ids, out_size,
            float(settings.lod_foveation),
        )  # fmt: skip
        return out_ids[:k], out_size[:k], int(total)

    def kept_bounds(self, keep: PointFilter | None) -> tuple[np.ndarray, np.ndarray]:
        """(most, likely): per node, the most points the load filter ``keep`` keeps of it (what its
        classes let pass, known from the octree's class counts where it has them, else all its
        points) and those it likely keeps, known before any is loaded: the most times the share
        of the node's box inside the clip box (``PointFilter.box_shares``, at least
        MIN_KEPT_SHARE: a node barely inside is not taken for free). The first selection of a
        frame weighs nodes by the likely (through classes alone, with class counts: what each
        keeps, so it spends the budget in full and is the only one). Made once a filter."""
        if keep is None:
            return self.counts, self.counts
        asked = (keep, len(self.keys))  # (a COPC/EPT hierarchy grows as its pages are read)
        if self._kept_bounds[0] != asked:
            has_classes = self.class_counts is not None and bool(keep.classes or keep.drop_classes)
            most = kept_by_class(self.class_counts, len(self.keys), keep) if has_classes else self.counts
            shares = np.maximum(keep.box_shares(self.box_min, self.box_min + self.box_size), MIN_KEPT_SHARE)
            likely = np.ceil(most * shares).astype(np.int64) if keep.clip else most
            self._kept_bounds = (asked, (most, likely))
        return self._kept_bounds[1]

    def knows_kept(self, keep: PointFilter | None) -> bool:
        """Whether every node's points the load filter ``keep`` keeps are known before any is
        loaded: through classes alone, from the class counts (``kept_bounds``)."""
        return keep is not None and not keep.needs_positions and self.class_counts is not None

    def _attribute_dtypes(self) -> dict:
        return {a: v.dtype for a, v in self.attributes.items() if v.ndim == 1}

    def arena_layout(self) -> dict:
        """Arena keywords of the layout its nodes are held in: the three-word layout (a
        format-2 octree's: compact_octree.CompactOctree)."""
        return {}

    def class_facts(self) -> dict:
        """What its files tell of the LAS classes its points hold: the viewer's class toggles list
        them before any node is read. A gigapoint octree's class counts (``classes.npy``) name
        exactly those held; else its metadata's ``metadata_class_facts``."""
        if self.class_counts is not None:
            return {"classes": np.unique(self.class_counts["class"][self.class_counts["count"] > 0]).tolist()}
        return self.metadata_class_facts()

    def metadata_class_facts(self) -> dict:
        """What its metadata tells of the LAS classes its points hold (``known_classes``: the
        readers keep it in ``meta``)."""
        return {k: self.meta[k] for k in ("classes", "class_range") if k in self.meta}

    def new_arena(self, points: int) -> Arena:
        """An empty arena of at least ``points`` points for this octree's nodes."""
        arena = Arena(points, self.name, self.bounds, self._attribute_dtypes(), **self.arena_layout())
        arena.source_scale = self.meta.get("scale")  # (format 2: positions are exact on it)
        return arena

    def prepare(self, view: View, settings) -> DrawList:
        """The frame's nodes made resident in the arena, one batch per arena slot."""
        check_classified(self.name, self.attribute_names, settings.hidden_classes)
        ids = self._resident_selection(view, settings)
        keep = self.load_filter(settings.hidden_classes)
        # (no round where the class counts tell what every node keeps: the first selection weighed it all)
        rounds = KEPT_ROUNDS if keep is not None and not self.knows_kept(keep) else 0
        for r in range(rounds):
            # the nodes just loaded count their kept points from now on, not their estimates:
            # an estimate too low drops the nodes past the budget, one too high leaves budget to
            # deeper nodes, until a selection loads none (every node it draws weighed by its
            # kept points: within the budget). The last round weighs the nodes not loaded whole,
            # so what it loads fits whatever they keep.
            loads = self.arena.loads
            ids = self._resident_selection(view, settings, estimated=r < rounds - 1)
            if self.arena.loads == loads:
                break
        arena = self.arena
        recs = self.nodes[ids]
        _, size = visible_and_size(view.rows, recs["bbox_min"], recs["bbox_max"], view.width, view.height, view.near, view.far)
        bits = precision_for(size, settings.precision_threshold_px) if settings.adaptive_precision else np.full(len(ids), 30, np.int32)
        mats = batch_matrices(view.rows, recs["bbox_min"], recs["bbox_max"])
        slot_lists = [arena.resident[nd] for nd in ids.tolist()]
        n_slots = np.array([len(s) for s in slot_lists], np.int64)
        slots = np.concatenate(slot_lists) if slot_lists else np.empty(0, np.int64)
        owner = np.repeat(np.arange(len(ids)), n_slots)
        # node by node in the Morton order of their cubes (writes that stay in one part of the
        # image at a time), not in the arena's order, which mixes the levels loaded frame by frame
        order = np.lexsort((slots, self.morton_position[ids][owner]))
        slots, owner = slots[order], owner[order]
        sel = Selection(slots.astype(np.int64), bits[owner].astype(np.int32), mats[owner], size[owner], int(len(self.keys) - len(ids)))
        spacing = None
        if settings.point_sizing == "adaptive":  # its sizes from the nodes drawn finest (issue #17)
            if self._node_spacing is None:  # the hierarchy's share of ancestors' points, once: nodes never change
                self._union_gain = union_gain(self.children, self.counts)
                self._node_spacing = np.full(len(self.counts), np.nan)  # each node's own, measured when first drawn finest
            spacing = finest_spacing(arena, sel.ids, owner, ids, self.children, self.counts, self._union_gain, self._node_spacing)
        return DrawList(arena, sel, len(self.nodes), nodes=ids, spacing=spacing)

    def _resident_selection(self, view: View, settings, estimated: bool = True) -> np.ndarray:
        """The nodes a view selects (those with points; ``estimated`` as ``select_nodes``), made
        resident in the arena (one made or grown where they do not fit)."""
        keep = self.load_filter(settings.hidden_classes)
        if self.arena is not None:
            self.arena.show(keep)  # (another filter: every node loaded again)
        ids, _, total = self.select_nodes(view, settings, estimated)
        ids = ids[self.nodes["count"][ids] > 0]
        if self.arena is None or self.arena.n_points < total:
            cap = max(total, min(int(settings.point_budget), self.n_points)) * 5 // 4 + 64 * ARENA_CHUNK
            self._grow_arena(min(cap, self.n_points + (len(self.keys) + 1) * ARENA_CHUNK))
        arena = self.arena
        arena.show(keep)
        if not arena.ensure(ids, self):
            # a selection of many small nodes that wastes slots: grow and retry once
            self._grow_arena(arena.n_points * 2 + (len(ids) + 1) * ARENA_CHUNK).ensure(ids, self)
        return ids

    def _grow_arena(self, points: int) -> Arena:
        """A new arena of ``points`` points in place of the octree's (more than it has), holding
        what it held (``Arena.take_over``)."""
        arena = self.new_arena(points)
        if self.arena is not None and (self.arena.med is None) == (arena.med is None):
            arena.take_over(self.arena)
        elif self.arena is not None:  # one set by hand in the other layout: its nodes loaded again, as it showed them
            arena.show(self.arena.keep)
        self.arena = arena
        return arena

    def prepare_views(self, views, settings) -> MultiViewDrawList | None:
        """None: each view selects its own nodes, so stereo draws the eyes one by one."""
        return None

    def reading(self) -> contextlib.nullcontext:
        """Nothing to hold beyond the frame: ``prepare`` fills the arena, which no one else writes."""
        return contextlib.nullcontext()


def known_classes(codes=None, low=None, high=None) -> dict:
    """{"classes": the LAS classes a cloud holds} where its metadata lists them (an EPT schema's
    counts, a Potree attribute's histogram), else {"class_range": (low, high)} where it bounds
    them, else {}. What is not a class (a float, 300) is left unsaid: metadata that cannot tell
    costs the viewer's list its precision, not the cloud its opening."""
    def is_class(c) -> bool:  # (JSON's 2.0 too: Potree's min and max are floats)
        return isinstance(c, (int, float)) and not isinstance(c, bool) and float(c).is_integer() and 0 <= c <= 255

    if codes is not None and all(is_class(c) for c in codes):
        return {"classes": sorted({int(c) for c in codes})}
    if is_class(low) and is_class(high) and low <= high:
        return {"class_range": (int(low), int(high))}
    return {}


def read_meta(d: OctreeDir) -> dict:
    """A gigapoint octree's metadata (``octree.json``), its format and version checked."""
    try:
        meta = json.loads(d.meta.read_text())
    except ValueError as exc:
        raise InputError(f"{d.meta}: invalid JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME or meta.get("version") not in FORMAT_VERSIONS:
        raise InputError(f"{d.meta}: not a gigapoint octree of version {' or '.join(map(str, FORMAT_VERSIONS))}")
    try:  # what places and counts the points: a cube of edge 0 drew nothing, bounds as a list failed inside
        if not is_whole_number(meta["points"]) or meta["points"] < 0:
            raise ValueError(f"points is not a count: {meta['points']!r}")
        edge, spacing = float(meta["cube_edge"]), meta.get("spacing")
        if not (math.isfinite(edge) and edge > 0):
            raise ValueError(f"cube_edge must be a positive number: {meta['cube_edge']!r}")
        if spacing is not None and not (math.isfinite(float(spacing)) and spacing >= 0):
            raise ValueError(f"spacing must be a number >= 0: {spacing!r}")
        attributes = meta.get("attributes", {})
        if not isinstance(attributes, dict) or not all(isinstance(a, str) for a in attributes):  # 5 was a TypeError
            raise TypeError(f"attributes is not {{name: dtype}}: {str(attributes)[:60]}")
        for a in attributes:  # each names a file: '/../../x' read x.npy from outside the folder (one named 'attr.' inside let it through)
            if attribute_name_problem(a):
                raise ValueError(attribute_name_problem(a)[:200])
        bounds = meta["bounds"]
        if not isinstance(bounds, dict):
            raise TypeError(f"bounds is not {{\"min\": [x, y, z], \"max\": [x, y, z]}}: {bounds!r}")
        frame = {"cube_min": meta["cube_min"], "bounds.min": bounds["min"], "bounds.max": bounds["max"]}
        if meta.get("scale") is not None:  # the source's grid (LAS inputs), null otherwise
            frame["scale"] = meta["scale"]
        check_placement(frame, positive="scale", box=("bounds.min", "bounds.max"))
        step = float(np.max(frame["scale"])) if "scale" in frame else 0.0
        tight_bounds(str(d.meta), "metadata (bounds, cube)", bounds["min"], bounds["max"], meta["cube_min"], edge, step)  # (bounds of 1e308 drew NaN)
    except KeyError as exc:
        raise InputError(f"{d.meta}: invalid metadata (no {exc.args[0]!r})") from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"{d.meta}: invalid metadata ({' '.join(str(exc).split())})") from None
    return meta


def check_placement(triples: dict, positive: str = "", box: tuple[str, str] | None = None) -> None:
    """Raise ValueError unless each of ``triples`` (name: value) is three finite numbers, the one
    named ``positive`` all above 0, and the ``box`` pair (min name, max name) ordered."""
    values = {}
    for name, v in triples.items():
        try:
            values[name] = a = np.asarray(v, np.float64)
        except (TypeError, ValueError):
            a = None
        if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
            raise ValueError(f"{name} is not three finite numbers: {v!r}")
    if positive in values and not np.all(values[positive] > 0):
        raise ValueError(f"{positive} must be positive: {values[positive].tolist()}")
    if box and not np.all(values[box[0]] <= values[box[1]]):
        raise ValueError(f"{box[0]} {values[box[0]].tolist()} exceeds {box[1]} {values[box[1]].tolist()}")


def read_gigapoint(octree_dir, meta: dict | None = None) -> OctreeCloud:
    """A gigapoint octree folder of format version 1 (an OctreeDir or a path) opened for
    rendering: its metadata checked, its arrays memory-mapped. ``reader.open_octree`` opens a
    folder of any kind (version 2: compact_octree.read_compact) and reads its class counts."""
    d = OctreeDir(octree_dir)
    p = d.path
    meta = read_meta(d) if meta is None else meta
    if meta["version"] != FORMAT_VERSION_WORDS:
        raise InputError(f"{d.meta}: a version {meta['version']} octree; open it with gigapoint.open")
    nodes = d.load("nodes", mmap=False)
    keys = d.load("keys", mmap=False)
    arrays = {k: d.load(k) for k in POINT_ARRAYS}
    attributes = {a: d.load(f"attr.{a}") for a in meta.get("attributes", {})}
    if nodes.dtype != BATCH_DTYPE or len(nodes) != len(keys):
        raise InputError(f"{p}: nodes.npy / keys.npy do not match the gigapoint layout")
    n = int(meta["points"])
    if any(len(a) != n for a in arrays.values()) or int(nodes["count"].astype(np.int64).sum()) != n:
        raise InputError(f"{p}: point arrays hold a different number of points than {d.meta.name} says ({n:,})")
    return OctreeCloud(meta.get("name", p.name), meta, nodes, keys, arrays, attributes, p)


def check_grid(name: str, what: str, scale, offset) -> None:
    """A one-line InputError unless a dataset's integer grid (its scale and offset per axis) can
    place points among drawable coordinates: a scale or offset beyond MAX_ABS_COORDINATE puts
    every point (off the grid's origin) beyond any (a damaged z scale of 2e277, finite and
    positive, decoded z of 1e286 and drew NaN; an offset of 1e308 drew inf)."""
    scale, offset = np.asarray(scale, np.float64), np.asarray(offset, np.float64)
    if not (np.all(np.abs(scale) <= MAX_ABS_COORDINATE) and np.all(np.abs(offset) <= MAX_ABS_COORDINATE)):
        raise InputError(
            f"{name}: corrupt {what}: scale {scale.tolist()} and offset {offset.tolist()} put its points beyond any coordinate (±{MAX_ABS_COORDINATE:g})"
        )


def tight_bounds(name: str, what: str, lo, hi, cube_min, edge: float, step: float = 0.0):
    """(lo, hi): the points' bounds a dataset states (a COPC file's LAS header, EPT's
    ``boundsConforming``), or its cube where they are missing, not finite, or all zero. Bounds
    beyond the cube (more than two ``step``s, the coordinates' grid, and 0.1 % of the cube) are a one-line
    InputError: one of the two is wrong, and a cube beside the points culled every node: a blank
    image and "no point is in view"."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    cube_min, cube_max = np.asarray(cube_min, np.float64), np.asarray(cube_min, np.float64) + edge
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)) or not (np.any(lo) or np.any(hi)):
        return cube_min, cube_max  # missing, or a writer's zeros: the cube stands in
    if outside_cube(lo, hi, cube_min, cube_max, step):
        raise InputError(
            f"{name}: corrupt {what}: the points' bounds {box_text(lo, hi)} lie outside the octree's cube {box_text(cube_min, cube_max)}; "
            "one of them is wrong"
        )
    return lo, hi


def outside_cube(lo, hi, cube_min, cube_max, step: float) -> bool:
    """Whether the box lo..hi lies beyond the cube by more than writers' rounding: two ``step``s
    (the coordinates' grid: a writer chooses its cubes before it rounds positions to the grid),
    0.1 % of the cube's edge and the coordinates' float rounding."""
    cube_min, cube_max = np.asarray(cube_min, np.float64), np.asarray(cube_max, np.float64)
    tol = 2.0 * abs(step) + 1e-3 * float(np.max(cube_max - cube_min)) + 1e-9 * float(np.max(np.abs(np.concatenate([cube_min, cube_max]))))
    return bool(np.any(np.asarray(lo) < cube_min - tol) or np.any(np.asarray(hi) > cube_max + tol))


def box_text(lo, hi) -> str:
    """'[x0..x1, y0..y1, z0..z1]' of a box, for messages."""
    return "[" + ", ".join(f"{a:.6g}..{b:.6g}" for a, b in zip(lo.tolist(), hi.tolist())) + "]"
