"""What the files say of their coordinate reference system: its name and identity, its units
(WKT1, WKT2, compound CRSs, LAS GeoTIFF keys; pyproj for a bare EPSG code where installed), its
WKT and EPSG code, and a warning where files disagree."""

from __future__ import annotations

import functools
import math
import re
import threading
from pathlib import Path

from ..errors import GigapointError, GigapointWarning, InputError, warn
from ._base import read_once
from .las import EPSG_LENGTH_UNITS, LasHeader, LasReader, geokeys, read_las_header, wkt_of
from .paths import file_names
from .ply import PlyReader
from .registry import file_header, reader_for

WKT_EPSG = re.compile(r'(?:AUTHORITY|ID)\[\s*"EPSG"\s*,\s*"?(\d+)"?\s*\]\s*\]\s*$', re.IGNORECASE)

#: The name a WKT CRS starts with (PROJCS["WGS 84 / UTM zone 10N",...)
WKT_NAME = re.compile(r'\s*[A-Z_]+\[\s*"([^"]+)"')


def crs_name(crs: str | None) -> str:
    """A CRS as ``gigapoint info`` says it: a WKT by its name and EPSG code (the code ends it,
    past where 100 characters cut it), 'unknown' where none is named."""
    name, code = WKT_NAME.match(crs or ""), WKT_EPSG.search(crs or "")
    if name:
        return f"{name.group(1)} ({f'EPSG:{code.group(1)}' if code else 'WKT'})"
    return crs or "unknown"


def crs_identity(crs: str) -> str:
    """What tells two CRSs apart, the same for one CRS however a file writes it: 'EPSG:n', or
    'EPSG:h+v' for a compound CRS by its parts' codes (a WKT1 AUTHORITY or WKT2 ID, GeoTIFF keys'
    'EPSG:26910+5703' and a COMPD_CS of those two parts alike), else the first text of it read.
    With pyproj (``_pyproj_identity``) an ESRI WKT and PROJ's WKT of one projection are one CRS
    too (autzen's NAD_1983_HARN_Lambert_Conformal_Conic and EPSG:2994); without it, the codes its
    text names (``_text_identity``). Another zone, datum or unit stays another CRS.
    warn_mixed_crs, folder_info, change and the reprojection's clip polygon compare by it."""
    try:
        return _pyproj_identity(crs)
    except Exception:  # noqa: BLE001 - pyproj missing, or the text unknown to it: the codes the text names
        return _text_identity(crs)


_identity_lock = threading.Lock()
#: crs_identity of each CRS text pyproj has read: tiles by the thousand share a few texts
_identities: dict[str, str] = {}
#: (pyproj CRS, its parts' EPSG codes, identity) of each identity given, which a new text is compared with
_distinct_crss: list[tuple[object, tuple, str]] = []


def _pyproj_identity(crs: str) -> str:
    """``crs_identity`` by pyproj: the identity of a CRS read before that is the same one (its
    parts' EPSG codes the same, or ``CRS.equals`` ignoring axis order), else its own: its codes'
    'EPSG:h+v', or its text where a part has no code. Raises where pyproj is not installed or
    cannot read ``crs``."""
    import pyproj  # (first: where it is not installed, no identity it gave is taken)

    with _identity_lock:
        if crs in _identities:
            return _identities[crs]
    parsed = pyproj.CRS.from_user_input(crs.strip())
    parsed = parsed.source_crs if parsed.is_bound else parsed  # (a WKT1 with TOWGS84: the CRS it binds)
    codes = tuple(part.to_epsg() for part in pyproj_parts(parsed))
    coded = None not in codes
    with _identity_lock:
        # two CRSs with codes are the same where their codes are; CRS.equals (which reads its
        # other CRS again) only where one has none (an ESRI WKT)
        same = (
            key
            for seen, seen_codes, key in _distinct_crss
            if (codes == seen_codes if coded and None not in seen_codes else parsed.equals(seen, ignore_axis_order=True))
        )
        identity = next(same, None)
        if identity is None:
            identity = "EPSG:" + "+".join(map(str, codes)) if coded else crs
            _distinct_crss.append((parsed, codes, identity))
        _identities[crs] = identity
    return identity


@functools.lru_cache(maxsize=64)
def _text_identity(crs: str) -> str:
    """``crs_identity`` without pyproj: 'EPSG:h+v' or 'EPSG:n' of the codes the text names as its
    own ('EPSG:n+v' itself; a WKT's AUTHORITY / ID; a compound WKT's two parts' ones, else its
    own), else the text ('EPSG:5498', a registered compound code, is not told from its parts')."""
    horizontal, vertical = _epsg_codes(crs)
    tree = _wkt_tree(crs) if horizontal is None else None
    if tree is not None and tree[0] in ("COMPD_CS", "COMPOUNDCRS"):
        parts = [_wkt_epsg(p) for p in tree[1:] if isinstance(p, list) and p[0] in _WKT_KINDS]
        horizontal, vertical = parts if len(parts) == 2 and None not in parts else (_wkt_epsg(tree), None)
    elif tree is not None:
        horizontal = _wkt_epsg(tree)
    if horizontal is None:
        return crs
    return f"EPSG:{horizontal}" + (f"+{vertical}" if vertical is not None else "")


def own_epsg(crs: str) -> str | None:
    """'EPSG:n', or 'EPSG:h+v' of a compound CRS, where ``crs`` names itself by those codes (an
    'EPSG:n' text, a WKT's own AUTHORITY / ID, a compound WKT's parts': ``_text_identity``) and
    pyproj reads that back as a CRS; else None (a WKT naming no code of its own, no pyproj)."""
    identity = _text_identity(crs)
    return identity if EPSG_TEXT.fullmatch(identity) and crs_wkt(identity) else None


#: Symbols of the length units coordinates come in, by their size in metres (WKT names one unit
#: many ways: "US survey foot", "Foot_US"); another unit is shown by its name
LENGTH_SYMBOLS = ((1.0, "m"), (0.3048, "ft"), (1200 / 3937, "US ft"))
#: The length units of GeoTIFF keys (ProjLinearUnitsGeoKey, VerticalUnitsGeoKey) by EPSG code
_WKT_TOKEN = re.compile(r'\s*(?:"((?:[^"]|"")*)"|([\[\](),])|([^\[\](),"\s]+))')
_WKT_KINDS = {  # the CRS keywords of WKT1 and WKT2 whose axes' units are read
    "PROJCS": "projected", "PROJCRS": "projected", "PROJECTEDCRS": "projected",
    "GEOGCS": "geographic", "GEOGCRS": "geographic", "GEOGRAPHICCRS": "geographic",
    "VERT_CS": "vertical", "VERTCRS": "vertical", "VERTICALCRS": "vertical",
}  # fmt: skip


def _wkt_tree(text: str) -> list | None:
    """A WKT as nested lists, KEYWORD[a, b, ...] -> [KEYWORD, a, b, ...] (numbers and enum words
    as text); None where the text is not WKT ('EPSG:2992')."""
    stack = [[]]
    for quoted, bracket, word in _WKT_TOKEN.findall(text):
        if bracket in ("[", "("):
            if not stack[-1] or not isinstance(stack[-1][-1], str):
                return None
            node = [stack[-1].pop().upper()]
            stack[-1].append(node)
            stack.append(node)
        elif bracket in ("]", ")"):
            if len(stack) < 2:
                return None
            stack.pop()
        elif bracket != ",":
            stack[-1].append(word or quoted)
    root = stack[0][0] if len(stack) == 1 and len(stack[0]) == 1 else None
    return root if isinstance(root, list) else None


def _wkt_unit(node: list, angle: bool) -> dict | None:
    """{name, symbol, metres} of a UNIT / LENGTHUNIT / ANGLEUNIT node; an angle's metres are None."""
    try:
        name, size = str(node[1]), float(node[2])
    except (IndexError, ValueError):
        return None
    if angle or node[0] == "ANGLEUNIT":
        return {"name": name, "symbol": "°" if name.lower().startswith("deg") else name, "metres": None}
    return {"name": name, "symbol": next((s for m, s in LENGTH_SYMBOLS if math.isclose(size, m, rel_tol=1e-9)), name), "metres": size}


def _wkt_units(crs: list) -> tuple[dict | None, dict | None]:
    """(horizontal, vertical) units of one WKT CRS (a compound CRS's parts' in turn): those of its
    own axes (WKT2 may give each AXIS its unit; else the one UNIT for all), not its base CRS's."""
    kind = _WKT_KINDS.get(crs[0])
    if kind is None:  # a compound CRS: its parts; any other (geocentric, engineering): unknown
        parts = [_wkt_units(p) for p in crs[1:] if isinstance(p, list)] if crs[0] in ("COMPD_CS", "COMPOUNDCRS") else []
        return next((h for h, _ in parts if h), None), next((v for _, v in parts if v), None)
    nodes = [c for c in crs[1:] if isinstance(c, list)]
    units = [u for a in nodes if a[0] == "AXIS" for u in a if isinstance(u, list) and u[0].endswith("UNIT")]
    units = [_wkt_unit(u, kind == "geographic" and u[0] != "LENGTHUNIT") for u in units or [c for c in nodes if c[0].endswith("UNIT")]]
    if kind == "vertical":
        return None, units[0] if units else None
    if kind == "geographic":  # a 3D one's ellipsoidal height has a length unit
        return (units[0] if units else None), next((u for u in units if u and u["metres"] is not None), None)
    return (units[0] if units else None), (units[2] if len(units) == 3 else None)


def angular_across(units: dict) -> dict | None:
    """The horizontal unit of ``units`` (``crs_units``'s) where it is an angle (a geographic CRS:
    x and y in degrees, no lengths to measure areas, volumes or distances in), else None."""
    across = units["horizontal"]
    return across if across is not None and across["metres"] is None else None


def refuse_angles(where: str, source, crs: str | None, units: dict, operation: str, instead: str = "", bounds=None) -> None:
    """A one-line InputError where ``units``' x and y are angles (``angular_across``): no
    length, area or volume is measured in degrees. ``source`` names the file, ``operation``
    what needs lengths, ``instead`` another way out ('give both, or '); ``crs`` (None: not
    named) the CRS, ``units`` its io.crs_units; ``bounds`` (lo, hi) in
    longitude/latitude: their UTM zone is offered as the CRS to move them into."""
    angle = angular_across(units)
    if angle is None:
        return
    target = "EPSG:n of a projected CRS"
    if bounds is not None:
        lon, lat = ((float(lo) + float(hi)) / 2 for lo, hi in zip(bounds[0][:2], bounds[1][:2]))
        if -180 <= lon <= 180 and -80 <= lat <= 84:  # (UTM's reach)
            zone = min(int((lon + 180) // 6) + 1, 60)
            target = f"EPSG:{(32600 if lat >= 0 else 32700) + zone}, WGS 84 / UTM zone {zone}{'N' if lat >= 0 else 'S'}, where the data lie"
    raise InputError(
        f"{where}: {source} has coordinates in {angle['name']}s{f' ({crs_name(crs)})' if crs else ''}; {operation} needs metres or feet: "
        f"{instead}reproject first (gigapoint convert --to-crs {target})"
    )


def file_crs(path) -> tuple[str | None, LasHeader | None, bool]:
    """(the CRS ``path`` names, its LAS header, whether its format can name one): a LAS/LAZ
    header's (its WKT, else 'EPSG:n' or 'EPSG:n+v' of its GeoTIFF keys: LasHeader.crs), a PLY
    header's ``comment crs`` line (no LAS header); None for none named, and for another format
    (False: it cannot, so it is not said to lack one). Each header read once an operation; a
    file gone or damaged raises its reader's error."""
    reader = reader_for(path)
    if isinstance(reader, LasReader):
        hdr = read_las_header(path, salvage=True)  # (a file cut off still names its CRS)
        return hdr.crs(), hdr, True
    if isinstance(reader, PlyReader):
        return file_header(path, salvage=True)["crs"], None, True
    return None, None, False


def first_named_crs(files) -> tuple[object, str, LasHeader | None] | None:
    """(the file, its CRS, its LAS header or None) of the first file of ``files`` that names a
    CRS (``file_crs``); None where none does (a file gone or damaged since it was read: skipped)."""
    for f in files:
        try:
            crs, hdr, _ = file_crs(f)
        except (GigapointError, OSError):  # gone or damaged since it was read: its read says why
            continue
        if crs:
            return f, crs, hdr
    return None


def first_crs(files) -> tuple[object, str, dict, LasHeader | None] | None:
    """(the file, its CRS, ``crs_units`` of it, its LAS header or None) of ``first_named_crs``
    (a LAS header's GeoTIFF unit keys read too); None where no file names one. What files_crs,
    files_units, files_length_units and a clip polygon's placing read."""
    found = first_named_crs(files)
    if found is None:
        return None
    f, crs, hdr = found
    return f, crs, crs_units(crs, None if hdr is None else geokeys(hdr.vlrs)), hdr


def first_crs_wkt(files) -> tuple[str, str | None] | None:
    """(the CRS, its WKT) of ``first_named_crs``: the WKT its LAS (E)VLRs
    hold, else ``crs_wkt`` of its CRS (GeoTIFF keys' or a PLY comment's 'EPSG:n': None without
    pyproj). What a conversion's output names."""
    found = first_named_crs(files)
    if found is None:
        return None
    crs, hdr = found[1], found[2]
    return crs, (None if hdr is None else wkt_of(hdr.vlrs + hdr.evlrs)) or crs_wkt(crs)


def files_length_units(where: str, files, operation: str | None, instead: str = "") -> dict:
    """``files_units`` of ``files``, and where ``operation`` is given (what needs lengths: None,
    nothing does) ``refuse_angles`` for the file they are read from, its CRS named: one header
    read (each file's in turn, up to the first naming a CRS), not one for each. A LAS header's
    bounds offer their UTM zone; a PLY header has none (no points read for them)."""
    found = first_crs(files)
    if found is None:
        return crs_units(None)
    path, crs, units, hdr = found
    if operation is not None:
        refuse_angles(where, path, crs, units, operation, instead, None if hdr is None else (hdr.mins, hdr.maxs))
    return units


def crs_units(crs: str | None, geokeys: dict[int, int] | None = None) -> dict:
    """The units of a CRS's coordinates, for lengths measured in them: {"horizontal": U,
    "vertical": U, "vertical_assumed": bool}, each U {name, symbol, metres} or None (unknown).

    From a WKT (``crs``: the projected CRS's axes' UNIT, a compound CRS's vertical part's), else
    from LAS GeoTIFF keys (``geokeys``: ProjLinearUnitsGeoKey 3076, VerticalUnitsGeoKey 4099), else
    from an EPSG code ('EPSG:n', or the keys' ProjectedCSTypeGeoKey 3072 / GeographicTypeGeoKey 2048
    without a unit key, as LAS 1.2 files often name theirs; 'EPSG:n+v''s n, and v for the heights)
    through pyproj's axes where pyproj is installed (``_epsg_units``; without it such a code says none). A geographic CRS's horizontal
    unit is an angle (metres None: its x and y are no lengths). Where a CRS names no vertical unit, heights
    are taken to be in the horizontal length unit (LAS files are; ``vertical_assumed`` says so).
    """
    tree = _wkt_tree(crs or "")
    horizontal, vertical = _wkt_units(tree) if tree else (None, None)
    keys = geokeys or {}
    if horizontal is None and keys.get(1024) == 2:  # GTModelTypeGeoKey: geographic
        horizontal = {"name": "degree", "symbol": "°", "metres": None}
    elif horizontal is None and keys.get(3076) in EPSG_LENGTH_UNITS:
        horizontal = _wkt_unit(["UNIT", *EPSG_LENGTH_UNITS[keys[3076]]], angle=False)
    if vertical is None and keys.get(4099) in EPSG_LENGTH_UNITS:
        vertical = _wkt_unit(["UNIT", *EPSG_LENGTH_UNITS[keys[4099]]], angle=False)
    code = _epsg_code(crs, keys) if horizontal is None else None
    if code is not None:  # ("unknown" units in the viewer for EPSG:2994's feet, EPSG:26910's metres)
        horizontal, up = _epsg_units(code)
        vertical = vertical or up
    vertical_code = _epsg_codes(crs)[1]
    if vertical is None and vertical_code is not None:  # 'EPSG:26910+5703': its vertical CRS's axis
        vertical = _epsg_units(vertical_code)[1]
    assumed = vertical is None and horizontal is not None and horizontal["metres"] is not None
    return {"horizontal": horizontal, "vertical": horizontal if assumed else vertical, "vertical_assumed": assumed}


def horizontal_epsg(crs: str | None) -> int | None:
    """The EPSG code of a CRS's horizontal part: an 'EPSG:n''s n (a registered compound code's
    horizontal part's where pyproj is installed: ``_compound_horizontal``), 'EPSG:n+v''s n; a WKT
    projected or geographic CRS's own AUTHORITY / ID (a compound CRS's horizontal part's: its
    whole one names no map grid GeoTIFF keys can hold); None where none is named (autzen's WKT
    names only its datum's and unit's codes, inside it)."""
    tree = _wkt_tree(crs or "")
    if tree is None:
        horizontal, vertical = _epsg_codes(crs)
        return _compound_horizontal(horizontal) if horizontal is not None and vertical is None else horizontal
    if tree[0] in ("COMPD_CS", "COMPOUNDCRS"):
        tree = next((p for p in tree[1:] if isinstance(p, list) and _WKT_KINDS.get(p[0]) in ("projected", "geographic")), None)
    if tree is None or _WKT_KINDS.get(tree[0]) not in ("projected", "geographic"):
        return None
    return _wkt_epsg(tree)


def _compound_horizontal(code: int) -> int | None:
    """The code of EPSG:``code``'s horizontal part where it is a registered compound CRS (EPSG:5498,
    NAD83 + NAVD88 height: 4269; None where that part has no code), by pyproj; ``code`` itself for
    any other, and where pyproj is not installed or knows no such code (the text cannot tell)."""
    try:
        import pyproj

        whole = pyproj.CRS.from_epsg(code)
        if not whole.is_compound:
            return code
        return next((c.to_epsg() for c in whole.sub_crs_list if not c.is_vertical), None)
    except Exception:  # noqa: BLE001 - pyproj missing or the code unknown to it: taken as it is
        return code


def _wkt_epsg(crs: list) -> int | None:
    """The EPSG code a WKT CRS node names as its own (its last AUTHORITY / ID: not its datum's or
    unit's, which lie inside those nodes); None without one."""
    codes = [n[2] for n in crs[1:] if isinstance(n, list) and n[0] in ("AUTHORITY", "ID") and len(n) > 2 and str(n[1]).upper() == "EPSG"]
    return int(codes[-1]) if codes and str(codes[-1]).isdigit() else None


def vertical_crs(crs: str | None) -> dict | None:
    """The vertical part of a CRS, what its heights are measured from and in (a compound CRS's:
    NAVD88 height of EPSG:26910+5703): {"epsg": its code or None, "name": its name, "unit": U as
    crs_units' or None}; None where the CRS has none (a 2D one, autzen's). Read by pyproj where
    installed (``_pyproj_vertical``: a registered compound code, 'EPSG:26910+5703', a WKT2 whose
    parts carry no ID of their own); else from a WKT's VERT_CS / VERTCRS part (``_wkt_vertical``),
    or the code of 'EPSG:n+v' (named by it, its unit unknown)."""
    if not crs:
        return None
    try:
        return _pyproj_vertical(crs)
    except Exception:  # noqa: BLE001 - pyproj missing, or the CRS unknown to it: the text's own words
        vertical_code = _epsg_codes(crs)[1]
        return {"epsg": vertical_code, "name": f"EPSG:{vertical_code}", "unit": None} if vertical_code else _wkt_vertical(crs)


def _pyproj_vertical(crs: str) -> dict | None:
    """``vertical_crs`` by pyproj: the vertical CRS that ``crs`` is or holds (a compound one's part,
    its code as pyproj identifies it); raises where pyproj is not installed or cannot read ``crs``."""
    import pyproj

    part = next((c for c in pyproj_parts(pyproj.CRS.from_user_input(crs.strip())) if c.is_vertical), None)
    if part is None:
        return None
    axes = list(part.axis_info)
    return {"epsg": part.to_epsg(), "name": part.name, "unit": _axis_unit(axes[0]) if axes else None}


def pyproj_parts(crs) -> list:
    """The parts of a pyproj CRS: a compound one's (horizontal, vertical), else itself alone; of a
    WKT1 with TOWGS84, those of the CRS it binds."""
    whole = crs.source_crs if crs.is_bound else crs
    return whole.sub_crs_list if whole.is_compound else [whole]


def pyproj_horizontal(crs, bound: bool = False):
    """The horizontal part of a pyproj CRS (a compound one's), None where it has none (a vertical
    CRS); unbound, as CRSs are compared (``same_horizontal``), unless ``bound``: then a WKT1's
    TOWGS84 is kept, as a pyproj Transformer moves x and y by it (unbound, by PROJ's own datum
    shift: metres apart)."""
    if bound and crs.is_bound:
        return crs  # (one bound whole, a compound one too: its x and y move as its horizontal part's)
    part = next((c for c in pyproj_parts(crs) if not c.is_vertical), None)
    return part.source_crs if part is not None and part.is_bound and not bound else part


def same_horizontal(one, other) -> bool:
    """Whether two pyproj CRSs have one horizontal CRS (the whole CRSs where one has no horizontal
    part), by pyproj's ``equals`` ignoring axis order."""
    horizontal, other_horizontal = pyproj_horizontal(one), pyproj_horizontal(other)
    if horizontal is None or other_horizontal is None:
        horizontal, other_horizontal = one, other
    return horizontal.equals(other_horizontal, ignore_axis_order=True)


def _wkt_vertical(crs: str) -> dict | None:
    """``vertical_crs`` of a WKT (a vertical CRS, or a compound one's vertical part): the code it
    names as its own; None for any other text ('EPSG:n' without pyproj: unknown)."""
    tree = _wkt_tree(crs)
    if tree is not None and tree[0] in ("COMPD_CS", "COMPOUNDCRS"):
        tree = next((p for p in tree[1:] if isinstance(p, list) and _WKT_KINDS.get(p[0]) == "vertical"), None)
    if tree is None or _WKT_KINDS.get(tree[0]) != "vertical" or len(tree) < 2 or not isinstance(tree[1], str):
        return None
    return {"epsg": _wkt_epsg(tree), "name": tree[1], "unit": _wkt_units(tree)[1]}


#: A CRS named by EPSG codes alone: 'EPSG:n', or a compound one 'EPSG:n+v' (LasHeader.crs of GeoTIFF keys)
EPSG_TEXT = re.compile(r"\s*EPSG:(\d+)(?:\+(\d+))?\s*", re.IGNORECASE)


def _epsg_codes(crs: str | None) -> tuple[int | None, int | None]:
    """(n, v) of an 'EPSG:n+v' ``crs``, (n, None) of an 'EPSG:n'; (None, None) of other text."""
    named = EPSG_TEXT.fullmatch(crs or "")
    return (int(named.group(1)), int(named.group(2)) if named.group(2) else None) if named else (None, None)


def _epsg_code(crs: str | None, keys: dict[int, int]) -> int | None:
    """The first EPSG code of an 'EPSG:n' or 'EPSG:n+v' ``crs`` (LasHeader.crs of GeoTIFF keys),
    else of the keys' projected or geographic CRS (not 32767: user-defined); None without one."""
    code = _epsg_codes(crs)[0]
    if code is not None:
        return code
    return next((keys[k] for k in (3072, 2048) if 0 < keys.get(k, 0) < 32767), None)


def _epsg_units(code: int) -> tuple[dict | None, dict | None]:
    """(horizontal, vertical) units of EPSG:``code`` by pyproj's axes (``axis_info``: east/north
    and up ones; a geographic CRS's across in angles; a geocentric one's none), (None, None) where
    pyproj is not installed (an optional dependency) or knows no such code."""
    try:
        import pyproj

        crs = pyproj.CRS.from_epsg(code)
        axes, geographic = list(crs.axis_info), bool(crs.is_geographic)
    except Exception:  # noqa: BLE001 - pyproj missing or the code unknown to it: units unknown
        return None, None
    across = [a for a in axes if str(a.direction).lower() in ("east", "north", "west", "south")]
    up = [a for a in axes if str(a.direction).lower() == "up"]
    return (_axis_unit(across[0], angle=geographic) if across else None), (_axis_unit(up[0]) if up else None)


def _axis_unit(axis, angle: bool = False) -> dict | None:
    """{name, symbol, metres} of a pyproj axis's unit (an angle's metres None)."""
    return _wkt_unit(["UNIT", axis.unit_name, axis.unit_conversion_factor], angle=angle)


def files_units(files) -> dict:
    """``crs_units`` of the first file of ``files`` that names a CRS (``first_crs``); all unknown without one."""
    return files_crs_units(files)[1]


def files_crs_units(files) -> tuple[str | None, dict]:
    """(``files_crs``, ``files_units``) of ``files`` from one read of the header naming the CRS."""
    found = first_crs(files)
    return (found[1], found[2]) if found else (None, crs_units(None))


def files_crs(files) -> str | None:
    """The CRS of the first LAS/LAZ file of ``files`` that names one: its WKT, else 'EPSG:n' (or
    'EPSG:n+v') of its GeoTIFF keys (LasHeader.crs); else a PLY file's (``first_crs``); None without one."""
    found = first_crs(files)
    return found[1] if found else None


def crs_wkt(crs: str | None) -> str | None:
    """WKT of a CRS as the readers give it: an 'EPSG:n' or 'EPSG:n+v' through pyproj when it
    is installed (else None); any other is WKT already."""
    if not crs or not crs.upper().startswith("EPSG:"):
        return crs or None
    try:
        import pyproj

        return pyproj.CRS.from_user_input(crs).to_wkt()
    except Exception:  # noqa: BLE001 - pyproj missing or the code unknown: no WKT
        return None


def warn_mixed_crs(files, then: str = "") -> None:
    """Warn where LAS/LAZ and PLY files read as one cloud name different CRSs, or some name one and
    others none (lost with their VLRs, or another CRS unsaid): their coordinates are used as
    they are, nothing is reprojected, so such tiles may not line up (``then``: what follows,
    added to the message). Once an operation (``headers_once``: open_sized reads the files twice)."""
    if len(files) < 2:
        return
    first: dict = {}  # CRS (crs_identity: one however each file writes it): the first file naming it
    have, none = 0, []  # how many files name a CRS; those naming none
    for f in files:
        try:  # (the header the read uses: no second open; salvage: as scan_angles_differ)
            crs, _, can_name = file_crs(f)
            if not can_name:  # (a format with no CRS to name: not said to lack one)
                continue
        except GigapointError:  # a bad file: reading its points says so, in its own words
            continue
        if crs:
            first.setdefault(crs_identity(crs), f)
            have += 1
        else:
            none.append(f)
    lacking = f"{file_names(none)} {'names' if len(none) == 1 else 'name'} no CRS"
    if len(first) > 1:
        named = "; ".join(f"{Path(f).name}: {crs[:60]}" for crs, f in list(first.items())[:3])
        said = f"the files name {len(first)} different CRSs ({named}{'; ...' if len(first) > 3 else ''}){'; ' + lacking if none else ''}"
        line_up = "so they do not line up"
    elif first and none:  # (the others' points probably in another CRS, or their VLRs lost)
        crs, f = next(iter(first.items()))
        others = f"{Path(f).name} names" if have == 1 else f"{Path(f).name} and {have - 1} more name"
        said, line_up = f"{lacking}, where {others} {crs[:60]}", "so they may not line up"
    else:
        return
    message = f"{said}: their coordinates are used as they are, not reprojected, {line_up}{then}"
    read_once("mixed CRSs", "\n".join(map(str, files)), lambda: warn(message, GigapointWarning))
