"""EPT (Entwine Point Tile, entwine.io): an ``ept.json`` with ``ept-hierarchy/`` and ``ept-data/``
beside it, local or over HTTP, opened as an octree (EptCloud).

``ept.json``: ``bounds`` (the octree's cube: xmin, ymin, zmin, xmax, ymax, zmax),
``boundsConforming`` (the points' bounds), ``points``, ``dataType`` (``laszip``: every node a
LAZ file ``ept-data/d-x-y-z.laz``; ``binary``: the schema's dimensions packed in order,
little-endian, ``ept-data/d-x-y-z.bin``; ``zstandard``: binary compressed with Zstandard,
``ept-data/d-x-y-z.zst``, read with the zstandard package), ``hierarchyType`` (``json``), ``schema`` (name, type
signed/unsigned/float, size, scale and offset per dimension; those beyond the LAS fields,
Entwine's OriginId, are attributes under their own names, scaled once: by a laszip node's
extra-bytes VLR where it scales them, else by the schema; a node's extra-bytes array of several
values a point, ``normal``, gives the dimensions PDAL splits it into, ``normal0`` ..; a node that
disagrees with the schema is refused) and ``srs`` (wkt, authority,
horizontal). The hierarchy: ``ept-hierarchy/0-0-0-0.json`` maps node names to point counts,
-1 for a node whose subtree is in ``ept-hierarchy/<name>.json``, read when a frame draws it
(voxel_octree.py).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from ..core.chunk import safe_attribute_name
from ..errors import InputError
from ..io import laz_process
from ..io.http import ByteSource, last_name, open_source, shown_url
from ..io.las import scan_angle_units
from ..io.las_kernels import _scaled_xyz
from .copc import ExtraField
from .kinds import EPT_FILE, ept_location
from .octree_dir import FORMAT_NAME
from .store import check_grid, known_classes, tight_bounds
from .voxel_octree import VoxelOctree, parse_voxel_name, voxel_name

DATA_TYPES = {"laszip": ".laz", "binary": ".bin", "zstandard": ".zst"}
_TYPES = {("signed", 1): "i1", ("signed", 2): "<i2", ("signed", 4): "<i4", ("signed", 8): "<i8"}
_TYPES.update({("unsigned", 1): "u1", ("unsigned", 2): "<u2", ("unsigned", 4): "<u4", ("unsigned", 8): "<u8"})
_TYPES.update({("float", 4): "<f4", ("float", 8): "<f8"})
#: EPT (PDAL) dimension names -> gigapoint attribute names and dtypes (as the LAS reader names them)
ATTRIBUTES = {
    "Intensity": ("intensity", np.uint16),
    "Classification": ("classification", np.uint8),
    "ReturnNumber": ("return_number", np.uint8),
    "NumberOfReturns": ("number_of_returns", np.uint8),
    "PointSourceId": ("point_source_id", np.uint16),
    "GpsTime": ("gps_time", np.float64),
    "Infrared": ("nir", np.uint16),
    "UserData": ("user_data", np.uint8),
    "ScanDirectionFlag": ("scan_direction_flag", np.uint8),
    "EdgeOfFlightLine": ("edge_of_flight_line", np.uint8),
    "ScanAngleRank": ("scan_angle", np.int16),  # PDAL's degrees (any format's) in LAS 1.4 units, as COPC's
    "ScanChannel": ("scanner_channel", np.uint8),
}
#: PDAL's ClassFlags (LAS's classification flags in one byte): its bits as the LAS reader names them
CLASS_FLAGS = {"synthetic": 0, "key_point": 1, "withheld": 2, "overlap": 3}
#: the schema's dimensions that are not attributes of their own (positions, colours, the flags above)
NOT_EXTRA = {"X", "Y", "Z", "Red", "Green", "Blue", "ClassFlags", *ATTRIBUTES}


def _srs_text(srs) -> str | None:
    if not isinstance(srs, dict):
        return None
    if srs.get("authority") and srs.get("horizontal"):
        text = f"{srs['authority']}:{srs['horizontal']}"
        return text + (f"+{srs['vertical']}" if srs.get("vertical") else "")
    return srs.get("wkt") or None


MAX_NODE_POINTS = 2**40  # a node's point count beyond this is a damaged hierarchy, not a node
ROOT_HEAD_READ = 64 * 1024  # the root node's LAS header and VLRs, read at open (_root_node_fields)
MAX_ROOT_HEAD = 16 * 1024 * 1024  # VLRs longer than this: a damaged header, not read at open


def _class_meta(schema: list[dict]) -> dict:
    """What ept.json's schema says of the classes held (store.known_classes as ``classes`` or
    ``class_range``): the values its Classification counts (Entwine writes them with its
    statistics), else its minimum and maximum."""
    for d in schema:
        if d.get("name") == "Classification":
            counts = d.get("counts")
            listed = isinstance(counts, list) and all(isinstance(c, dict) for c in counts)
            codes = [c.get("value") for c in counts if c.get("count") != 0] if listed else None
            return known_classes(codes, d.get("minimum"), d.get("maximum"))
    return {}


def _named_ept(name: str) -> bool:
    """Whether the file ``name`` (a path or a URL, its query aside) is called ept.json."""
    return last_name(name) == EPT_FILE


class EptCloud(VoxelOctree):
    """An EPT dataset opened as an octree: ``ept.json`` and the root hierarchy file at open,
    deeper hierarchy files and node files when a frame draws them. ``meta`` holds ``crs``,
    ``data_type`` and ``schema``."""

    def __init__(self, source: ByteSource):
        self.source = source
        name = source.name
        try:
            meta = json.loads(source.read_all())
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(f"{name}: not valid JSON ({' '.join(str(exc).split())})") from None
        if not isinstance(meta, dict):
            raise InputError(f"{name}: not an EPT ept.json (expected a JSON object)")
        missing = [k for k in ("bounds", "points", "dataType", "hierarchyType", "schema") if k not in meta]
        if missing:  # (a URL's any .json is taken for EPT's)
            lacks = f"lacks {', '.join(repr(k) for k in missing)}"
            if "hierarchy" in meta and "encoding" in meta:
                what = "a Potree metadata.json; Potree octrees open"
            elif meta.get("format") == FORMAT_NAME:  # ('…/tree/octree.json' was "ept.json lacks 'dataType', ...")
                what = "a converted octree's octree.json; converted octrees open"
            else:
                raise InputError(f"{name}: ept.json {lacks}" if _named_ept(name) else f"{name}: not an EPT ept.json (it {lacks})")
            raise InputError(f"{name}: {what} from a local folder (over HTTP: COPC files and EPT datasets)")
        self.data_type = meta["dataType"]
        if self.data_type not in DATA_TYPES:
            raise InputError(f"{name}: EPT dataType {self.data_type!r} is not supported (laszip, binary or zstandard)")
        if self.data_type == "zstandard":
            try:
                import zstandard  # noqa: F401  (said at open, not at the first frame)
            except ImportError:
                raise InputError(f"{name}: EPT dataType 'zstandard' needs the zstandard package (pip install 'gigapoint[lod]')") from None
        if meta["hierarchyType"] != "json":
            raise InputError(f"{name}: EPT hierarchyType {meta['hierarchyType']!r} is not supported (json)")
        try:
            b = np.array(meta["bounds"], np.float64).reshape(6)
            tight = np.array(meta.get("boundsConforming", meta["bounds"]), np.float64).reshape(6)
            n_points = int(meta["points"])
            if n_points < 0 or n_points != meta["points"]:  # -5 was taken as the cloud's count
                raise ValueError(f"points must be a whole number >= 0, got {meta['points']!r}")
            self._schema(meta["schema"])
            self.coordinate_step = max(self._scales.get(axis, (0.0, 0.0))[0] for axis in "XYZ")
        except (TypeError, ValueError, KeyError) as exc:
            raise InputError(f"{name}: invalid ept.json ({' '.join(str(exc).split())})") from None
        if not (np.all(np.isfinite(b)) and np.all(b[3:] > b[:3])):
            raise InputError(f"{name}: invalid ept.json bounds {b.tolist()}")
        check_grid(name, "ept.json schema", [self._scales[a][0] for a in "XYZ"], [self._scales[a][1] for a in "XYZ"])
        cube_min, edge = b[:3], float(np.max(b[3:] - b[:3]))
        lo, hi = tight_bounds(name, "ept.json (boundsConforming, bounds)", tight[:3], tight[3:], cube_min, edge, self.coordinate_step)
        if self.data_type == "laszip" and any(f.scaling is None for f in self._extras.values()):
            # a dimension the schema does not scale may be scaled by a laszip node's extra-bytes
            # VLR (floats then): the dtypes are fixed at open, so the root node's says, and every
            # node is checked against them when decoded (_node_field)
            root = self._root_node_fields()
            self._attr_dtypes.update(
                {a: np.dtype(np.float64) for a, f in self._extras.items() if f.scaling is None and f.name in root and root[f.name].scaling}
            )
        cloud_meta = {
            "format": "ept",
            "points": n_points,
            "cube_min": cube_min.tolist(),
            "cube_edge": edge,
            "bounds": {"min": lo.tolist(), "max": hi.tolist()},
            "span": meta.get("span"),
            "crs": _srs_text(meta.get("srs")),
            "data_type": self.data_type,
            "schema": [d["name"] for d in meta["schema"]],
            "version": meta.get("version"),
            **_class_meta(meta["schema"]),
        }
        stem = Path(name.rstrip("/")).parent.name or "ept"
        self._open(stem, cloud_meta, "0-0-0-0", path=None)

    def _schema(self, schema) -> None:
        """The binary record layout, per-dimension scale/offset and the attributes it holds."""
        fields, self._scales = [], {}
        for d in schema:
            t = _TYPES.get((d["type"], int(d["size"])))
            if t is None:
                raise ValueError(f"dimension {d.get('name')!r} has an unknown type {d['type']!r} of size {d['size']}")
            fields.append((d["name"], t))
            scale, offset = float(d.get("scale", 1.0)), float(d.get("offset", 0.0))
            if not (np.isfinite(scale) and scale > 0 and np.isfinite(offset)):  # X at scale 0 drew every point on one line
                raise ValueError(f"dimension {d['name']!r} has scale {scale} and offset {offset}: a positive scale and a finite offset are needed")
            self._scales[d["name"]] = (scale, offset)
        names = [f for f, _ in fields]
        for axis in ("X", "Y", "Z"):
            if axis not in names:
                raise ValueError(f"the schema has no {axis} dimension")
        self.record = np.dtype(fields)
        self._has_rgb = all(c in names for c in ("Red", "Green", "Blue"))
        self._attr_dtypes = {a: np.dtype(dt) for n, (a, dt) in ATTRIBUTES.items() if n in names}
        if "ClassFlags" in names:
            self._attr_dtypes.update(dict.fromkeys(CLASS_FLAGS, np.dtype(np.uint8)))
        # the other dimensions (Entwine's OriginId, a source's extra bytes) are attributes under
        # their own names, as the LAS and COPC readers read extra bytes; a laszip node holds
        # them as LAS extra bytes. Scaled where the schema gives a scale or offset (a laszip
        # node's extra-bytes VLR may scale them instead: _node_field).
        self._extras: dict[str, ExtraField] = {}  # attribute -> its dimension as the schema stores and scales it
        for d in schema:
            name = safe_attribute_name(d["name"])
            if d["name"] in NOT_EXTRA or name is None or name in self._attr_dtypes:
                continue
            scale, offset = self._scales[d["name"]] if "scale" in d or "offset" in d else (None, None)
            self._extras[name] = ExtraField(d["name"], self.record.fields[d["name"]][0], scale, offset)
            self._attr_dtypes[name] = self._extras[name].value_dtype

    def _root_node_fields(self) -> dict[str, ExtraField]:
        """``_node_fields`` of the root node's LAZ, read from its head: the attribute dtypes are
        fixed at open, and a laszip node's extra-bytes VLR may scale a dimension the schema does
        not (floats then). {} where the root node's file is missing (a root of no points) or
        has no readable LAS header (said when a frame decodes it)."""
        import laspy

        tile = self.source.sibling(self._node_path("0-0-0-0"))
        try:
            head = tile.read_head(ROOT_HEAD_READ)
            data_start = int.from_bytes(head[96:100], "little") if len(head) >= 100 else 0
            if len(head) < data_start <= MAX_ROOT_HEAD:  # (VLRs beyond the first read: a long WKT)
                head += tile.read(len(head), data_start - len(head))  # (the rest only, not its first bytes again)
            return _node_fields(laspy.LasHeader.read_from(io.BytesIO(head)))
        except (InputError, laspy.errors.LaspyException, ValueError):
            return {}

    # -- VoxelOctree
    def _fetch_pages(self, locators: list) -> list[bytes]:
        return self.source.read_all_many([self.source.sibling(f"ept-hierarchy/{n}.json") for n in locators])

    def _parse_page(self, blob: bytes, locator) -> tuple[dict, dict]:
        where = f"ept-hierarchy/{locator}.json"
        try:
            page = json.loads(blob)
        except (ValueError, UnicodeDecodeError) as exc:
            raise InputError(f"{self.source.name}: {where} is not valid JSON ({' '.join(str(exc).split())})") from None
        if not isinstance(page, dict):
            raise InputError(f"{self.source.name}: {where} is not a JSON object of node names and point counts")
        entries, pages = {}, {}
        for node, count in page.items():
            try:
                key = parse_voxel_name(node)
            except ValueError as exc:
                raise InputError(f"{self.source.name}: {where}: {exc}") from None
            if not isinstance(count, int) or isinstance(count, bool) or not -1 <= count <= MAX_NODE_POINTS:  # (2**63: an OverflowError)
                raise InputError(f"{self.source.name}: {where}: node {node} has an invalid point count {count!r}")
            if count == -1:
                pages[key] = node
            else:
                entries[key] = (count, node if count > 0 else None)
        return entries, pages

    def _fetch_nodes(self, locators: list) -> list[bytes]:
        return self.source.read_all_many([self.source.sibling(self._node_path(n)) for n in locators])

    def _node_path(self, name: str) -> str:
        return f"ept-data/{name}{DATA_TYPES[self.data_type]}"

    def node_file(self, key: int) -> str:
        """The node's own file (path or URL): a damaged one was said as ept.json's."""
        return self.source.sibling(self._node_path(voxel_name(key))).name

    def _decode(self, index: int, blob: bytes) -> dict:
        n = int(self.counts[index])
        need = n * self.record.itemsize
        held = f"{len(blob):,} bytes"
        if self.data_type == "zstandard":
            import zstandard

            # frames need not say their size (Entwine's do not): read at most one byte past the
            # records the hierarchy counts, so a damaged count or frame can't ask for GBs
            blob = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(blob)).read(need + 1)
            held = f"more than {need:,} bytes unpacked" if len(blob) > need else f"{len(blob):,} bytes unpacked"
        if self.data_type != "laszip":
            if len(blob) != need:
                raise InputError(
                    f"{self.node_file(int(self.keys[index]))}: holds {held}, {n:,} points of {self.record.itemsize} bytes need {need:,}"
                )
            rec = np.frombuffer(blob, self.record)
            xyz = np.empty((n, 3), np.float64)
            for i, axis in enumerate("XYZ"):
                s, o = self._scales[axis]
                xyz[:, i] = rec[axis].astype(np.float64) * s + o
            rgb = np.stack([rec["Red"], rec["Green"], rec["Blue"]], axis=1).astype(np.uint16) if self._has_rgb else None
            attrs = {a: rec[d] for d, (a, _) in ATTRIBUTES.items() if d in self.record.names}
            if "ScanAngleRank" in self.record.names:
                attrs["scan_angle"] = scan_angle_units(rec["ScanAngleRank"])
            if "ClassFlags" in self.record.names:
                attrs.update({a: (rec["ClassFlags"] >> np.uint8(bit)) & np.uint8(1) for a, bit in CLASS_FLAGS.items()})
            attrs.update({a: f.values(rec) for a, f in self._extras.items()})
            return {"xyz": xyz, "rgb": rgb, "attributes": attrs}
        import laspy

        # the node's LAZ: its header read here, its points decoded in a child process
        # (io/laz_process.py: lazrs crashes on some corrupt data)
        try:
            header = laspy.LasHeader.read_from(io.BytesIO(blob))
        except (laspy.errors.LaspyException, ValueError) as exc:  # random bytes after 'LASF' (PDAL's lone-star-invalid-tile): only "'utf-8' codec can't decode"
            key = int(self.keys[index])
            raise InputError(f"{self.node_file(key)}: cannot decode node {voxel_name(key)}: no readable LAS header ({' '.join(str(exc).split())})") from None
        if header.point_count != n:  # (before anything is sized by a header's count)
            raise InputError(
                f"{self.node_file(int(self.keys[index]))}: holds {header.point_count:,} points, the hierarchy says {n:,}"
            )
        laszip = header.vlrs[header.vlrs.index("LasZipVlr")].record_data  # (ValueError, said as the node's: not a LAZ)
        records = laz_process.decode_block(blob, laszip, header.point_count * header.point_format.size, skip=header.offset_to_point_data)
        pts = laspy.PackedPointRecord(records.view(header.point_format.dtype()), header.point_format)
        raw = pts.array
        xyz = np.empty((len(raw), 3), np.float64)
        _scaled_xyz(raw["X"], raw["Y"], raw["Z"], np.asarray(header.scales, np.float64), np.asarray(header.offsets, np.float64), xyz)
        dims = set(header.point_format.dimension_names)
        rgb = np.stack([pts["red"], pts["green"], pts["blue"]], axis=1).astype(np.uint16) if {"red", "green", "blue"} <= dims else None
        attrs = {a: np.asarray(pts[a]) for a, _ in ATTRIBUTES.values() if a in dims}  # laspy's names are gigapoint's
        if "scan_angle_rank" in dims:  # formats 0-5 (Entwine's): degrees
            attrs["scan_angle"] = scan_angle_units(pts["scan_angle_rank"])
        attrs.update({a: np.asarray(pts[a]) for a in CLASS_FLAGS if a in self._attr_dtypes and a in dims})
        # the extra dimensions: the node's LAS extra bytes of the same names (absent ones: zeros),
        # from the stored records (laspy's pts[dim] is already scaled where the VLR scales it)
        node_fields, key = _node_fields(header), int(self.keys[index])
        attrs.update({a: self._node_field(key, a, f, node_fields[f.name]).values(raw) for a, f in self._extras.items() if f.name in node_fields})
        return {"xyz": xyz, "rgb": rgb, "attributes": attrs}

    def _node_field(self, key: int, attr: str, schema: ExtraField, node: ExtraField) -> ExtraField:
        """How a laszip node's extra dimension becomes values: by its extra-bytes VLR's scale and
        offset where it gives them (how its bytes are stored, as laspy and PDAL read them), else
        by the schema's. Refused in one line where the node disagrees with the schema so that its
        values would be wrong: both scale it, differently; the schema scales a type the node does
        not store (already scaled values, scaled again); or its values do not fit the attribute's
        dtype, fixed at open (scaled values cast to whole numbers, int32 to uint8); or it holds
        several values a point (an array type), where the schema gives one. A value of the
        node's array that the schema names as a dimension it was split into (``normal0``:
        _node_fields) is checked as a dimension of its own."""
        dtype = self._attr_dtypes[attr]
        field = node if node.scaling else ExtraField(node.name, node.dtype, schema.scale, schema.offset, node.element)
        if node.dtype.shape:  # (an array type, 3 x int16: its dtype was said as numpy's ('<i2', (3,)))
            problem = f"holds {node.dtype.shape[0]} values a point ({node.dtype.shape[0]} x {node.dtype.base}), where ept.json's schema gives it one ({schema.dtype})"
        elif node.scaling and schema.scaling and node.scaling != schema.scaling:
            problem = "is stored * {:g} + {:g} (its extra-bytes VLR), ept.json's schema says * {:g} + {:g}".format(*node.scaling, *schema.scaling)
        elif schema.scaling and not node.scaling and node.dtype != schema.dtype:
            problem = f"is stored as {node.dtype}, unscaled, where ept.json's schema scales stored {schema.dtype}"
        elif not (np.can_cast(field.value_dtype, dtype, "safe") or field.value_dtype.kind == dtype.kind == "f"):
            scaled = " (scaled by its extra-bytes VLR)" if node.scaling else f" (stored as {node.dtype})"
            problem = f"gives {field.value_dtype} values{scaled}, where the dataset's {attr!r} is {dtype} (ept.json's schema, its root node)"
        else:
            return field
        of_array = "" if node.element is None else f" (value {node.element} of the node's array {node.name!r})"
        raise InputError(f"{self.node_file(key)}: node {voxel_name(key)}'s extra dimension {schema.name!r}{of_array} {problem}: its values would be wrong")


def _node_fields(header) -> dict[str, ExtraField]:
    """{dimension: ExtraField} of a LAS header's extra bytes, as its extra-bytes VLR stores them
    (laspy's names, those of its point records). An array of k values a point (``normal``,
    3 x float64) is a field of them all (a schema that names it as one dimension is refused:
    _node_field) and each value, scaled by its own scale and offset, under the names of the
    dimensions it is split into: PDAL's ``normal0`` .. (its LAS reader's, so Entwine's schema)
    and the LAS reader's ``normal_0`` ..; a dimension of the node that has such a name is itself."""
    out, split = {}, {}
    for d in header.point_format.extra_dimensions:
        scales = [None] * d.num_elements if d.scales is None else [float(s) for s in d.scales]
        offsets = [None] * d.num_elements if d.offsets is None else [float(o) for o in d.offsets]
        if d.num_elements == 1:
            out[d.name] = ExtraField(d.name, d.dtype, scales[0], offsets[0])
            continue
        out[d.name] = ExtraField(d.name, d.dtype)
        for k in range(d.num_elements):
            value = ExtraField(d.name, d.dtype.base, scales[k], offsets[k], element=k)
            split.update({f"{d.name}{k}": value, f"{d.name}_{k}": value})
    return {**split, **out}


def open_ept(path_or_url) -> EptCloud:
    """An EPT dataset (its ``ept.json``, its folder, or their URL) as an octree (EptCloud)."""
    loc = ept_location(path_or_url)
    if loc is None:
        raise InputError(f"{shown_url(path_or_url)}: not an EPT dataset (no ept.json)")
    return EptCloud(open_source(loc))
