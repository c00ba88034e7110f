"""Octrees whose hierarchy comes in pages and whose nodes are fetched as blobs: COPC (copc.py)
and EPT (ept.py), local or over HTTP (io/http.py).

**Keys.** COPC and EPT name a node by its VoxelKey ``(d, x, y, z)``: level d and the node's
integer position in the 2^d grid of the octree's cube (EPT's file names ``d-x-y-z``).
gigapoint keys (keys.py) are ``1 << 3d | prefix`` with the prefix's octal digit at every level
``x·4 + y·2 + z`` (Potree's child order), so a key is the VoxelKey's three coordinates
interleaved bit by bit, x on top, below a sentinel bit: ``voxel_to_key`` / ``key_to_voxel``.

**VoxelOctree** is an OctreeCloud (store.py) like the Potree reader: ``prepare`` selects nodes
largest-projected-first within the point budget and the arena copies them in by
``node_arrays``, which fetches the node's blob, decodes it (the subclass's ``_decode``) and
quantizes it against its tight bbox. The hierarchy is read from its root page at open; a
node whose entries lie in a page not read yet is a *pending* node (no points, its cube as its
box) until a frame selects it, when its page is read (several at once) and the node set is
rebuilt, resident nodes kept. Before the arena loads a frame's new nodes their blobs are
fetched together (``read_many``: several HTTP requests in flight). Every page is checked as
it is read: entries inside the file, keys inside the page's subtree, no key twice, no page
read twice (a hierarchy that refers to itself), so a bad file fails in one line naming it.
"""

from __future__ import annotations

import numpy as np

from ..core.chunk import DEFAULT_COLOR, ColorScaler
from ..core.layout import BATCH_DTYPE
from ..core.quantize import quantize
from ..errors import GigapointWarning, InputError, warn
from ..io import file_names
from ..io.laz_process import bad_data
from .keys import MAX_LEVEL, ROOT_KEY, key_cube, level_of
from .octree_dir import POINT_ARRAYS
from .store import OctreeCloud, box_text, outside_cube

#: Points of the fetched nodes decoded together (``VoxelOctree._decode_batch``).
DECODE_GROUP_POINTS = 1 << 20
#: A COPC/EPT node name, as stored in COPC hierarchy entries.
VOXEL_KEY_DTYPE = np.dtype([("level", "<i4"), ("x", "<i4"), ("y", "<i4"), ("z", "<i4")])


# --------------------------------------------------------------------------- keys


def voxel_to_key(level, x, y, z) -> np.ndarray:
    """gigapoint keys (u64) of VoxelKeys (d, x, y, z) (arrays or scalars; checked by ``valid_voxels``)."""
    level = np.atleast_1d(np.asarray(level, np.int64))
    xyz = [np.atleast_1d(np.asarray(v, np.int64)).astype(np.uint64) for v in (x, y, z)]
    key = np.zeros(len(level), np.uint64)
    for bit in range(MAX_LEVEL):
        for axis, v in enumerate(xyz):
            key |= ((v >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + 2 - axis)
    return key | (np.uint64(1) << (np.uint64(3) * level.astype(np.uint64)))


def key_to_voxel(keys) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(d, x, y, z) int64 arrays of gigapoint keys."""
    keys = np.atleast_1d(np.asarray(keys, np.uint64))
    level = level_of(keys).astype(np.int64)
    prefix = keys ^ (np.uint64(1) << (np.uint64(3) * level.astype(np.uint64)))
    out = [np.zeros(len(keys), np.int64) for _ in range(3)]
    for bit in range(MAX_LEVEL):
        for axis in range(3):
            out[axis] |= ((prefix >> np.uint64(3 * bit + 2 - axis)) & np.uint64(1)).astype(np.int64) << bit
    return level, out[0], out[1], out[2]


def valid_voxels(level, x, y, z) -> np.ndarray:
    """Which VoxelKeys name a node gigapoint can hold: 0 <= d <= MAX_LEVEL, 0 <= x, y, z < 2^d."""
    level = np.asarray(level, np.int64)
    ok = (level >= 0) & (level <= MAX_LEVEL)
    side = np.left_shift(np.int64(1), np.clip(level, 0, MAX_LEVEL))
    for v in (x, y, z):
        v = np.asarray(v, np.int64)
        ok &= (v >= 0) & (v < side)
    return ok


def voxel_name(key: int) -> str:
    """'d-x-y-z' of a gigapoint key (EPT's file name, and how errors name a node)."""
    d, x, y, z = (int(v[0]) for v in key_to_voxel([key]))
    return f"{d}-{x}-{y}-{z}"


def parse_voxel_name(name: str) -> int:
    """gigapoint key of 'd-x-y-z'; ValueError when it is not one."""
    parts = name.split("-")
    if len(parts) != 4 or not all(p.isdigit() for p in parts):
        raise ValueError(f"not a node name d-x-y-z: {name!r}")
    d, x, y, z = (int(p) for p in parts)
    if not valid_voxels(d, x, y, z):
        raise ValueError(f"node {name} lies outside the octree (or deeper than {MAX_LEVEL} levels)")
    return int(voxel_to_key(d, x, y, z)[0])


def in_subtree(keys: np.ndarray, root: int) -> np.ndarray:
    """Which keys are ``root`` or lie below it."""
    keys = np.asarray(keys, np.uint64)
    lev = level_of(keys).astype(np.int64)
    root_level = (int(root).bit_length() - 1) // 3
    shift = np.clip(lev - root_level, 0, None).astype(np.uint64) * np.uint64(3)
    return (lev >= root_level) & ((keys >> shift) == np.uint64(root))


# --------------------------------------------------------------------------- the octree


class VoxelOctree(OctreeCloud):
    """An OctreeCloud read a page and a node at a time (see the module's docstring).

    Subclasses set ``source`` (a ByteSource, for messages and reading), ``_attr_dtypes``, and
    implement ``_fetch_pages(locators) -> [bytes]``, ``_parse_page(blob, locator) -> (entries
    {key: (count, node locator)}, pages {key: page locator})``, ``_fetch_nodes(locators) ->
    [bytes]`` and ``_decode(index, blob) -> {"xyz": float64 (n, 3), "rgb": u16 (n, 3) or None,
    "attributes": {name: array}}``; then call ``_open(name, meta, root_page_locator)``.
    """

    coordinate_step = 0.0  # the grid its coordinates are stored on (COPC: the LAS scale; EPT: its X/Y/Z scales)

    source = None
    _attr_dtypes: dict  # attribute name -> dtype (set by the subclass)

    def _open(self, name: str, meta: dict, root_page, path=None) -> None:
        self._name, self._meta, self._path = name, meta, path
        self._entries: dict[int, tuple[int, object]] = {}
        self._pending: dict[int, object] = {ROOT_KEY: root_page}
        self._pages_read: set = set()
        self._decoded: set[int] = set()  # keys whose record holds their tight bbox
        self._misplaced_said = False  # a node's points outside its cube: said once
        self._damaged: list[int] = []  # keys of the nodes whose points decoded far outside their cubes
        self._damage_text = ""  # what the first of them decoded to
        self._damage_said = False  # said once (``_say_damaged``)
        self._blobs: dict[int, bytes] = {}  # fetched ahead for the frame being prepared
        self._ahead: dict[int, dict] = {}  # decoded ahead (a group of the fetched ones)
        self._group_of: dict[int, list[int]] = {}  # fetched node -> the group it is decoded with
        self._colors = ColorScaler()
        self.node_reads = 0
        self.bytes_read = 0
        self.pages_read = 0
        self.arena = None
        self.keys = np.empty(0, np.uint64)
        self.nodes = np.zeros(0, BATCH_DTYPE)
        self.filtered_colors = False  # a COPC/EPT point has one color: its own
        self._load_pages([ROOT_KEY])

    def __repr__(self) -> str:
        lo, hi = self.bounds
        pending = f", {len(self._pending):,} hierarchy pages not read yet" if self._pending else ""
        return (
            f"{type(self).__name__}({self.source_name!r}, {self.n_points:,} points, {len(self.keys):,} nodes{pending}, "
            f"bounds {lo.tolist()} .. {hi.tolist()})"
        )

    @property
    def source_name(self) -> str:
        return self.source.name if self.source is not None else self._name

    def node_file(self, key: int) -> str:
        """What a message about node ``key``'s points names: the dataset (a COPC file holds
        every node); EPT names the node's own file."""
        return self.source_name

    def close(self) -> None:
        """Close the connections of a remote source (a local one holds nothing open)."""
        if self.source is not None:
            self.source.close()

    # -- hierarchy
    @property
    def pending_pages(self) -> int:
        """Hierarchy pages not read yet."""
        return len(self._pending)

    def load_hierarchy(self) -> None:
        """Read every hierarchy page (``gigapoint info``; a frame reads only the pages it draws)."""
        while self._pending:
            self._load_pages(sorted(self._pending))

    def read_pages_meeting(self, meets) -> None:
        """Read the hierarchy pages of the pending nodes whose cubes meet a region (``meets(lo, hi)``
        of (k, 3) boxes: which meet it), level after level, until no pending node meets it (a tool
        reading a part of the octree: lod/query.py)."""
        for _ in range(MAX_LEVEL + 2):  # (each round reads a level of pages at least)
            near = np.flatnonzero(meets(self.nodes["bbox_min"], self.nodes["bbox_max"]))
            waiting = [k for k in self.keys[near].tolist() if k in self._pending]
            if not waiting:
                return
            self._load_pages(waiting)

    def points_of_nodes(self, indices: list[int]):
        """(index, ``node_points``) of each node of ``indices``, their blobs fetched a group of
        about DECODE_GROUP_POINTS points at a time, together (ranged reads in flight at once, as a
        frame's are), so that no more than a group is held."""
        start = 0
        while start < len(indices):
            group, held = [], 0
            while start < len(indices) and (not group or held < DECODE_GROUP_POINTS):
                group.append(indices[start])
                held += int(self.counts[indices[start]])
                start += 1
            self._blobs = dict(zip(group, self._fetch_nodes([self.locators[i] for i in group])))
            try:
                points = [(i, self.node_points(i)) for i in group]
            finally:
                self._blobs = {}
            yield from points

    def _load_pages(self, keys: list[int]) -> None:
        locators = [self._pending[k] for k in keys]
        for k, loc in zip(keys, locators):
            if loc in self._pages_read:
                raise InputError(f"{self.source_name}: the hierarchy refers to itself (the page of node {voxel_name(k)} was read before)")
        if len(set(locators)) != len(locators):
            raise InputError(f"{self.source_name}: the hierarchy refers to itself (two nodes point to the same page)")
        blobs = self._fetch_pages(locators)
        for key, loc, blob in zip(keys, locators, blobs):
            self._pages_read.add(loc)
            entries, pages = self._parse_page(blob, loc)
            self._merge_page(key, entries, pages)
        self.pages_read += len(keys)
        self._install()

    def _merge_page(self, page_key: int, entries: dict, pages: dict) -> None:
        where = "the root hierarchy page" if page_key == ROOT_KEY else f"the hierarchy page of node {voxel_name(page_key)}"
        if page_key in pages:
            raise InputError(f"{self.source_name}: the hierarchy refers to itself ({where} points to itself)")
        new = np.array(sorted(set(entries) | set(pages)), np.uint64)
        if len(new):
            outside = ~in_subtree(new, page_key)
            if outside.any():
                raise InputError(f"{self.source_name}: {where} holds node {voxel_name(int(new[outside][0]))}, outside its subtree")
        for k in new.tolist():
            if k in self._entries or (k in self._pending and k != page_key):
                raise InputError(f"{self.source_name}: node {voxel_name(k)} appears twice in the hierarchy")
        del self._pending[page_key]
        self._entries.update(entries)
        self._pending.update(pages)

    def _install(self) -> None:
        """Rebuild the node records (sorted keys, parents filled in as empty nodes) from the
        entries read so far, keeping decoded bboxes and the arena's resident nodes."""
        have = set(self._entries) | set(self._pending) | {ROOT_KEY}
        for k in list(have):
            while k > ROOT_KEY:
                k >>= 3
                if k in have:
                    break
                have.add(k)
        keys = np.array(sorted(have), np.uint64)
        counts = np.array([self._entries.get(k, (0, None))[0] for k in keys.tolist()], np.int64)
        meta = self._meta
        if not self._pending and int(counts.sum()) != meta["points"]:
            # the hierarchy read whole: the cloud's count is what its nodes hold (PDAL's reader
            # goes by them too), the header's or ept.json's kept for ``info`` to say beside it
            meta.setdefault("stated_points", meta["points"])
            meta["points"] = int(counts.sum())
        lo, hi = (np.array(meta["bounds"][b], np.float64) for b in ("min", "max"))
        nodes = np.zeros(len(keys), BATCH_DTYPE)
        nodes["level"] = level_of(keys)
        nodes["count"] = counts
        nodes["first"] = np.cumsum(counts) - counts
        cmin, cedge = key_cube(keys, meta["cube_min"], float(meta["cube_edge"]))
        full = counts > 0
        nodes["bbox_min"] = np.where(full[:, None], np.clip(cmin, lo, hi), cmin)
        nodes["bbox_max"] = np.where(full[:, None], np.clip(cmin + cedge[:, None], lo, hi), cmin + cedge[:, None])
        old_keys, old_nodes, arena = self.keys, self.nodes, self.arena
        pos = np.searchsorted(keys, old_keys)  # every old key is kept: its new index
        if len(old_keys):
            decoded = np.isin(old_keys, np.array(sorted(self._decoded), np.uint64))
            nodes["bbox_min"][pos[decoded]] = old_nodes["bbox_min"][decoded]
            nodes["bbox_max"][pos[decoded]] = old_nodes["bbox_max"][decoded]
        filtered = self.filtered_colors
        self.locators = [self._entries.get(k, (0, None))[1] for k in keys.tolist()]
        OctreeCloud.__init__(self, self._name, meta, nodes, keys, {}, {}, self._path)
        self.filtered_colors = filtered
        if arena is not None:  # resident nodes keep their slots (and nodes what they kept) under their new indices
            arena.renumber(pos, len(keys))
            self.arena = arena

    # -- per frame
    def prepare(self, view, settings):
        """Read the pages of the pending nodes a view selects (until none is selected), fetch the
        new nodes' blobs together, then draw as any OctreeCloud."""
        for _ in range(MAX_LEVEL + 2):
            ids, _, _ = self.select_nodes(view, settings)
            waiting = [k for k in self.keys[ids].tolist() if k in self._pending]
            if not waiting:
                break
            self._load_pages(waiting)
        if self.arena is not None:
            self.arena.show(self.load_filter(settings.hidden_classes))  # (another filter empties it: the nodes below are fetched again)
        resident = self.arena.resident if self.arena is not None else {}
        need = [i for i in ids.tolist() if self.counts[i] > 0 and i not in resident]
        if len(need) > 1:
            self._blobs = dict(zip(need, self._fetch_nodes([self.locators[i] for i in need])))
            # decoded a group at a time (``_decode_batch``, in parallel where the format allows),
            # in the order the arena loads them, so that no more than a group is held decoded
            group: list[int] = []
            held = 0
            for i in need:
                group.append(i)
                self._group_of[i] = group
                held += int(self.counts[i])
                if held >= DECODE_GROUP_POINTS:
                    group, held = [], 0
        try:
            return super().prepare(view, settings)
        finally:
            self._blobs, self._ahead, self._group_of = {}, {}, {}
            self._say_damaged()

    def _attribute_dtypes(self) -> dict:
        return dict(self._attr_dtypes)

    @property
    def attribute_names(self) -> list[str]:
        """The point attributes its nodes carry (drawn through the arena)."""
        return sorted(self._attr_dtypes)

    def node_arrays(self, index: int) -> tuple[dict, dict, int]:
        """Node ``index`` fetched (or taken from what ``prepare`` fetched ahead), decoded and
        quantized against its tight bbox (which its record holds from now on)."""
        n = int(self.nodes["count"][index])
        if n == 0:
            return self._blank(0)
        key = int(self.keys[index])
        if index not in self._ahead and len(self._group_of.get(index, ())) > 1:
            self._decode_ahead(self._group_of[index])
        d = self._ahead.pop(index, None)
        if d is None:
            blob = self._blobs.pop(index, None)
            if blob is None:
                blob = self._fetch_nodes([self.locators[index]])[0]
            self.node_reads += 1
            self.bytes_read += len(blob)
            try:
                d = self._decode(index, blob)
            except InputError:
                raise
            except BaseException as exc:  # any decoding failure is a corrupt node (lazrs's panics too: io/laz_process.bad_data)
                if not bad_data(exc):
                    raise
                raise InputError(f"{self.node_file(key)}: cannot decode node {voxel_name(key)} ({' '.join(str(exc).split())})") from None
        xyz = d["xyz"]
        if len(xyz) != n:
            raise InputError(f"{self.node_file(key)}: node {voxel_name(key)} holds {len(xyz):,} points, the hierarchy says {n:,}")
        if not np.isfinite(xyz).all():
            raise InputError(f"{self.node_file(key)}: node {voxel_name(key)} holds non-finite coordinates")
        cube_min, cube_max = self.nodes["bbox_min"][index].copy(), self.nodes["bbox_max"][index].copy()  # its cube until now
        if self._far_outside(key, xyz, cube_min, cube_max):  # damaged: the node is left empty from now on
            self._entries[key] = (0, None)  # (kept so when more pages are read: _install)
            self.nodes["count"][index] = self.counts[index] = 0
            self._meta["points"] -= n
            return self._blank(n)  # (n points of nothing: the arena, which asked for n, keeps none of them)
        rec = self.nodes[index : index + 1].copy()
        rec["first"] = 0
        low, med, high = quantize(xyz, np.arange(n, dtype=np.int64), rec)
        lo, hi = rec[0]["bbox_min"], rec[0]["bbox_max"]  # the points' tight box, which its record holds from now on
        self.nodes[index]["bbox_min"], self.nodes[index]["bbox_max"] = lo, hi
        if not self._misplaced_said and outside_cube(lo, hi, cube_min, cube_max, self.coordinate_step):
            self._misplaced_said = True  # drawn where they are, but the other nodes are culled by cubes that may be as wrong
            warn(
                f"{self.source_name}: node {voxel_name(key)}'s points {box_text(lo, hi)} lie outside its cube "
                f"{box_text(cube_min, cube_max)}: the octree's cube does not match its points; nodes may be missing from views",
                GigapointWarning,
            )
        self._decoded.add(key)
        rgba = np.empty((n, 4), np.uint8)
        rgba[:] = DEFAULT_COLOR
        rgb = d.get("rgb")
        if rgb is not None:
            rgb = np.asarray(rgb)
            shift = self._colors.int_shift(int(rgb.max())) if n else 0
            rgba[:, :3] = np.minimum(rgb >> shift, 255)
            rgba[:, 3] = 255
        color = rgba.view(np.uint32).reshape(-1)
        got = d.get("attributes", {})
        attrs = {a: (np.asarray(got[a]).astype(dt, copy=False) if a in got else np.zeros(n, dt)) for a, dt in self._attr_dtypes.items()}
        return {"low": low, "med": med, "high": high, "color": color, "rgba": color}, attrs, 0

    def node_points(self, index: int) -> dict:
        """As OctreeCloud's; a damaged node (``_far_outside``) is said, and holds none."""
        try:
            return super().node_points(index)
        finally:
            self._say_damaged()

    def _blank(self, n: int) -> tuple[dict, dict, int]:
        """``node_arrays`` of ``n`` zero points (an empty node, a damaged one)."""
        zero = np.zeros(n, np.uint32)
        return dict.fromkeys(POINT_ARRAYS, zero), {a: np.zeros(n, dt) for a, dt in self._attr_dtypes.items()}, 0

    def _far_outside(self, key: int, xyz: np.ndarray, cube_min, cube_max) -> bool:
        """Whether node ``key``'s points lie beyond its cube by more than the octree's cube edge
        (noted for ``_say_damaged``): LAZ's decoder turns damaged bytes into garbage kilometres
        away without an error. A cube a little off (a writer's rounding, a too large cube) is no
        damage: ``node_arrays`` draws those points and says the cube is wrong."""
        lo, hi = xyz.min(axis=0), xyz.max(axis=0)
        beyond = np.maximum(cube_min - lo, hi - cube_max)
        a = int(np.argmax(beyond))
        if not beyond[a] > float(self._meta["cube_edge"]):
            return False
        if not self._damaged:
            v = lo[a] if cube_min[a] - lo[a] >= hi[a] - cube_max[a] else hi[a]
            self._damage_text = f"{'xyz'[a]} {v:,.3f}, its cube {cube_min[a]:,.3f}..{cube_max[a]:,.3f}"
        self._damaged.append(key)
        return True

    def _say_damaged(self) -> None:
        """The damaged nodes found (``_far_outside``), said once an octree, after the frame (or
        ``to_memory``) that read them."""
        if self._damaged and not self._damage_said:
            self._damage_said = True
            many = len(self._damaged) > 1
            warn(
                f"{self.source_name}: corrupt point data: {'nodes' if many else 'node'} {file_names([voxel_name(k) for k in self._damaged])} "
                f"{'decode' if many else 'decodes'} to points far outside {'their cubes' if many else 'its cube'} "
                f"({f'node {voxel_name(self._damaged[0])}: ' if many else ''}{self._damage_text}); "
                f"{'their' if many else 'its'} data is damaged and is not drawn",
                GigapointWarning,
            )

    def _decode_ahead(self, group: list[int]) -> None:
        """The fetched nodes of ``group`` decoded together (``_decode_batch``); on any failure
        they are left to ``node_arrays``, whose one-by-one decoding names the broken node."""
        members = [j for j in group if j in self._blobs]
        for j in group:
            self._group_of.pop(j, None)
        if len(members) < 2:
            return
        blobs = [self._blobs[j] for j in members]
        try:
            decoded = self._decode_batch(members, blobs)
        except BaseException as exc:  # decoded again one by one, which reports the node
            if not bad_data(exc):
                raise
            decoded = None
        if decoded is None:
            return
        for j, blob, d in zip(members, blobs, decoded, strict=True):
            del self._blobs[j]
            self._ahead[j] = d
            self.node_reads += 1
            self.bytes_read += len(blob)

    def points_per_level(self) -> list[int]:
        """Points of each level (of the pages read so far: ``load_hierarchy`` reads them all)."""
        lev = self.nodes["level"].astype(np.int64)
        return np.bincount(lev, weights=self.counts, minlength=int(lev.max()) + 1).astype(np.int64).tolist()

    def to_memory(self) -> OctreeCloud:
        """Every node decoded into one in-memory OctreeCloud (small datasets; tests compare
        on-demand images with it)."""
        self.load_hierarchy()
        total = int(self.counts.sum())
        arrays = {k: np.empty(total, np.uint32) for k in ("low", "med", "high", "color")}
        arrays["rgba"] = arrays["color"]
        attrs = {name: np.zeros(total, dt) for name, dt in self._attr_dtypes.items()}
        for i in np.flatnonzero(self.counts > 0).tolist():
            s = slice(int(self.nodes["first"][i]), int(self.nodes["first"][i]) + int(self.counts[i]))
            src, src_attrs, _ = self.node_arrays(i)  # (a damaged node's: zeros, its count 0 from now on)
            for k in ("low", "med", "high", "color"):
                arrays[k][s] = src[k]
            for a, v in src_attrs.items():
                attrs[a][s] = v
        meta = dict(self.meta, points=int(self.counts.sum()))  # (less the damaged nodes')
        self._say_damaged()
        oc = OctreeCloud(self.name, meta, self.nodes.copy(), self.keys, arrays, attrs, self.path)
        oc.filtered_colors = False
        return oc

    # -- what subclasses implement
    def _fetch_pages(self, locators: list) -> list[bytes]:
        raise NotImplementedError

    def _parse_page(self, blob: bytes, locator) -> tuple[dict, dict]:
        raise NotImplementedError

    def _fetch_nodes(self, locators: list) -> list[bytes]:
        raise NotImplementedError

    def _decode(self, index: int, blob: bytes) -> dict:
        raise NotImplementedError

    def _decode_batch(self, indices: list[int], blobs: list[bytes]) -> list[dict] | None:
        """Several nodes' ``_decode`` at once (None: one by one)."""
        return None
