"""Frame: what a render produces — the visibility buffer and everything derived from it."""

from __future__ import annotations

import functools
import io
from dataclasses import dataclass, field

import numpy as np

from ..core.layout import EMPTY_PIXEL
from ..core.renderable import check_point_index
from ..errors import GigapointError

MAX_INDEX = 0xFFFFFFFF  # point indices live in the low 32 bits of the visibility buffer


@dataclass
class RenderStats:
    points_total: int = 0
    batches_total: int = 0
    batches_culled: int = 0
    batches_rendered: int = 0
    points_processed: int = 0
    precision_histogram: dict[int, int] = field(default_factory=lambda: {10: 0, 20: 0, 30: 0})
    visible_pixels: int = 0
    time_ms: float = 0.0
    raster_ms: float = 0.0
    backend: str = ""

    @property
    def points_per_second(self) -> float:
        return self.points_processed / (self.time_ms / 1000.0) if self.time_ms > 0 else 0.0

    @classmethod
    def of(cls, draw, counts: np.ndarray, points_total: int, time_ms: float, raster_ms: float, backend: str) -> RenderStats:
        """The stats of a DrawList whose selected batches drew ``counts`` points each."""
        sel = draw.selection
        return cls(
            points_total=points_total,
            batches_total=draw.n_batches,
            batches_culled=sel.n_culled,
            # an octree's batches are its nodes (total and culled count them): its nodes drawn, not
            # the chunks or arena slots they fill (culled + drawn was over the total)
            batches_rendered=len(sel.ids) if draw.nodes is None else len(draw.nodes),
            points_processed=int(counts.sum()),
            precision_histogram={b: int(counts[sel.bits == b].sum()) for b in (10, 20, 30)},
            time_ms=time_ms,
            raster_ms=raster_ms,
            backend=backend,
        )

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        d["precision_histogram"] = {str(k): v for k, v in self.precision_histogram.items()}
        d["points_per_second"] = self.points_per_second
        return d


def encode_image(image: np.ndarray, fmt: str = "JPEG", quality: int = 85) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    if fmt == "JPEG":
        Image.fromarray(np.ascontiguousarray(image[..., :3])).save(buf, "JPEG", quality=quality)
    else:
        Image.fromarray(np.ascontiguousarray(image)).save(buf, "PNG", compress_level=3)
    return buf.getvalue()


class Image(np.ndarray):
    """An (H, W, 4) uint8 RGBA picture (3 channels: RGB) that a notebook shows as a PNG and a
    terminal as one line; otherwise the plain array it views. What indexing, arithmetic, numpy's
    functions and its own methods (astype, reshape, .T, view...) make of it stays an Image while
    still a uint8 picture of that shape, and is a plain ndarray (or a number) else: a pixel, a
    channel, a float array, a mean."""

    def __getitem__(self, key):  # (a view keeps its class: image[0, 0] was an Image)
        return _as_image_if_one(super().__getitem__(key))

    def __array_wrap__(self, array, context=None, return_scalar=False):  # ufuncs: arithmetic, ==, reductions
        # (numpy 1.26's takes no return_scalar: a 0-d result is made a number below)
        return _as_image_if_one(super().__array_wrap__(array, context))

    def __array_function__(self, func, types, args, kwargs):  # np.mean, np.concatenate, ...
        return _as_image_if_one(super().__array_function__(func, types, args, kwargs))

    def view(self, *args, **kwargs):  # (a type asked for, as image.view(np.ndarray), is what it gets)
        out = super().view(*args, **kwargs)
        asks_type = any(isinstance(a, type) and issubclass(a, np.ndarray) for a in (*args, kwargs.get("type")))
        return out if asks_type else _as_image_if_one(out)

    @property
    def T(self):
        return self.transpose()

    def __repr__(self) -> str:  # a 1920x1080 image printed 8 million numbers
        if not _is_picture(self):  # (a subclass's, or one made by a method not wrapped below: numpy's repr)
            return super().__repr__()
        h, w, c = self.shape
        return f"Image({w}x{h} {'RGBA' if c == 4 else 'RGB'}, uint8)"

    def _repr_png_(self) -> bytes | None:
        return encode_image(self, "PNG") if _is_picture(self) else None


def _keeps_image_if_one(method):
    """``method`` of ndarray, whose result is an Image while it is a picture (as __getitem__'s)."""

    @functools.wraps(method)
    def image_if_one(self, *args, **kwargs):
        return _as_image_if_one(method(self, *args, **kwargs))

    return image_if_one


# ndarray's methods that make an array of another shape or dtype without a ufunc or numpy function
# (image.astype(float), image.reshape(-1, 4), image.ravel() stayed Images: numpy's repr, no picture)
for _name in ("astype", "reshape", "transpose", "swapaxes", "ravel", "flatten", "squeeze", "repeat", "take",
              "compress", "diagonal", "cumsum", "cumprod", "argsort", "argmax", "argmin"):  # fmt: skip
    setattr(Image, _name, _keeps_image_if_one(getattr(np.ndarray, _name)))


def _is_picture(a: np.ndarray) -> bool:
    return a.ndim == 3 and a.shape[2] in (3, 4) and a.dtype == np.uint8 and min(a.shape[:2]) > 0


def _as_image_if_one(a):
    """``a`` as an Image while it is a picture, else a plain ndarray; a 0-d one a number (a.sum())."""
    if not isinstance(a, np.ndarray):
        return a
    if a.ndim == 0 and type(a) is Image:
        return a.view(np.ndarray)[()]
    if _is_picture(a):
        return a if type(a) is Image else a.view(Image)
    return a.view(np.ndarray) if type(a) is Image else a


@dataclass(repr=False)  # the dataclass's repr printed the visibility buffer and the whole cloud
class Frame:
    visibility: np.ndarray  # (H, W) u64: depth bits << 32 | point index; all ones = empty
    image: np.ndarray  # (H, W, 4) uint8 RGBA
    stats: RenderStats
    # The point buffers the indices name (a PointCloud itself; an octree's arena), and their
    # version when drawn: while ``points.version == generation`` an index still names the
    # point this frame drew (``point_info``).
    points: object = None
    generation: int | None = None

    def __post_init__(self):
        self.image = self.image.view(Image)  # shown as a picture where a user looks at it

    def point_info(self, index: int) -> dict | None:
        """What the frame's point ``index`` is (position, color, attributes), or None for -1
        (an empty pixel: ``frame.index`` holds -1 where no point was drawn) and when the
        buffers have been rewritten since (an octree's arena, by a later frame). Another
        index outside the buffers, or one that is not a whole number (3.5 was read as 3), raises
        PointIndexError."""
        check_point_index(index)
        if index == -1 or self.points is None or self.points.version != self.generation:
            return None
        return self.points.point_info(index)  # every point buffer checks its own range (check_point_index)

    @property
    def empty(self) -> np.ndarray:
        return self.visibility == EMPTY_PIXEL

    @property
    def depth(self) -> np.ndarray:
        """(H, W) float32 distance along the view direction; inf where no point."""
        d = (self.visibility >> np.uint64(32)).astype(np.uint32).view(np.float32).copy()
        d[self.empty] = np.inf
        return d

    @property
    def index(self) -> np.ndarray:
        """(H, W) int64 index of the visible point into ``points``, the buffers drawn (a plain
        cloud's own; with ``hidden_classes`` its points of the other classes, in the same order:
        ``cloud.without_classes(hidden)``; an octree's arena); -1 where none. ``point_info`` reads it."""
        idx = (self.visibility & np.uint64(0xFFFFFFFF)).astype(np.int64)
        idx[self.empty] = -1
        return idx

    def __repr__(self) -> str:
        h, w = self.image.shape[:2]
        s = self.stats
        return f"Frame({w}x{h}, {s.points_processed:,} points drawn, {s.visible_pixels:,} pixels covered, {s.backend or '?'}, {s.time_ms:.1f} ms)"

    def _repr_png_(self) -> bytes:
        """The image, as a notebook shows the frame."""
        return encode_image(self.image, "PNG")


def check_indexable(points) -> None:
    """A visibility buffer names a point by 32 bits."""
    if points.n_points > MAX_INDEX:
        raise GigapointError(f"{points.name}: {points.n_points:,} points exceed the 2^32 a brute-force frame can index; convert it to an octree")
