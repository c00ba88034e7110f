"""The OpenGL baseline: the same points and view drawn as GL_POINTS through moderngl on an
offscreen EGL context (Mesa llvmpipe: OpenGL on the CPU)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from ..core.compact import rgba32
from ..errors import GigapointError
from ..render import Camera
from .scene import relative_chunks

_MESA_EGL_VENDOR = "/usr/share/glvnd/egl_vendor.d/50_mesa.json"


def first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__



_VERTEX_SHADER = """
#version 330
uniform mat4 mvp;
in vec3 in_pos;
in vec4 in_color;
out vec4 v_color;
void main() {
    gl_Position = mvp * vec4(in_pos, 1.0);
    v_color = in_color;
}
"""
_FRAGMENT_SHADER = """
#version 330
in vec4 v_color;
out vec4 f_color;
void main() {
    f_color = v_color;
}
"""


def gl_matrix(camera: Camera, near: float, far: float, center) -> np.ndarray:
    """float64 4x4 clip matrix for points given relative to ``center``, matching gigapoint's projection.

    Window x, y equal gigapoint's pixel coordinates (x'/w, y'/w, row 0 first in memory),
    so a framebuffer read back needs no flip; depth maps [near, far] to [-1, 1].
    """
    rows = camera.screen_rows()
    e4 = np.array([0.0, 0.0, 0.0, 1.0])
    w_row, depth = rows[2], rows[3]
    if camera.projection == "perspective":  # w == depth
        z_row = (far + near) / (far - near) * depth - 2.0 * far * near / (far - near) * e4
    else:  # w == 1
        z_row = 2.0 / (far - near) * depth - (far + near) / (far - near) * e4
    clip = np.stack([2.0 / camera.width * rows[0] - w_row, 2.0 / camera.height * rows[1] - w_row, z_row, w_row])
    to_world = np.eye(4)
    to_world[:3, 3] = center
    return clip @ to_world


class GLBaseline:
    """GL_POINTS of one cloud through moderngl on an offscreen EGL context (Mesa llvmpipe)."""

    def __init__(self, width: int, height: int, software: bool = True):
        try:
            import moderngl
        except ImportError as exc:
            raise GigapointError(f"GL baseline needs moderngl ({exc}); install with: pip install 'gigapoint[bench]'") from None
        self.mgl = moderngl
        # software: Mesa's llvmpipe even where a GPU driver exists (the baseline is GL on the CPU);
        # the variables only steer driver selection, so they are restored once the context exists.
        steer = {"LIBGL_ALWAYS_SOFTWARE": "1"}
        if Path(_MESA_EGL_VENDOR).is_file():
            steer["__EGL_VENDOR_LIBRARY_FILENAMES"] = _MESA_EGL_VENDOR
        saved = {k: os.environ.get(k) for k in steer} if software else {}
        try:
            if software:
                os.environ.update({k: os.environ.get(k, v) for k, v in steer.items()})
            self.ctx = moderngl.create_standalone_context(backend="egl", require=330)
        except Exception as exc:  # noqa: BLE001 - no libEGL, no driver, no display: say why in one line
            raise GigapointError(f"GL baseline: no EGL/OpenGL 3.3 context ({first_line(exc)})") from None
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        self.renderer = f"{self.ctx.info.get('GL_RENDERER', '?')} / {self.ctx.info.get('GL_VERSION', '?')}"
        self.prog = self.ctx.program(vertex_shader=_VERTEX_SHADER, fragment_shader=_FRAGMENT_SHADER)
        self.width, self.height = width, height
        self.fbo = self.ctx.framebuffer(
            color_attachments=[self.ctx.renderbuffer((width, height), 4)],
            depth_attachment=self.ctx.depth_renderbuffer((width, height)),
        )
        self.vao = None
        self._buffers: list = []

    def upload(self, cloud, center) -> None:
        """Float32 positions relative to ``center`` and u8 colors of every point, in cloud order."""
        self._release_buffers()
        n = cloud.n_points
        pos = self.ctx.buffer(reserve=n * 12)
        for first, chunk in relative_chunks(cloud, center):
            pos.write(chunk.tobytes(), offset=first * 12)
        col = self.ctx.buffer(rgba32(cloud.color))  # u32 RGBA8 (decoded from a compact cloud's)
        self._buffers = [pos, col]
        self.vao = self.ctx.vertex_array(self.prog, [(pos, "3f", "in_pos"), (col, "4f1", "in_color")])
        self.n_points = n

    def draw(self, matrix: np.ndarray, background=(0, 0, 0, 255)) -> float:
        """One frame (clear + draw + glFinish); its wall-clock seconds."""
        ctx = self.ctx
        t0 = time.perf_counter()
        self.fbo.use()
        ctx.enable(self.mgl.DEPTH_TEST)
        ctx.point_size = 1.0
        self.prog["mvp"].write(matrix.T.astype("f4").tobytes())  # GL reads column-major
        self.fbo.clear(*(c / 255.0 for c in background), depth=1.0)
        self.vao.render(self.mgl.POINTS)
        ctx.finish()
        return time.perf_counter() - t0

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W, 4) uint8 image (row 0 = gigapoint's top row) and (H, W) bool coverage."""
        img = np.frombuffer(self.fbo.read(components=4, alignment=1), np.uint8).reshape(self.height, self.width, 4)
        depth = np.frombuffer(self.fbo.read(components=1, attachment=-1, dtype="f4", alignment=1), np.float32).reshape(
            self.height, self.width
        )
        return img.copy(), depth < 1.0

    def _release_buffers(self) -> None:
        if self.vao is not None:
            self.vao.release()
            self.vao = None
        for b in self._buffers:
            b.release()
        self._buffers = []

    def release(self) -> None:
        self._release_buffers()
        self.fbo.release()
        self.prog.release()
        self.ctx.release()


