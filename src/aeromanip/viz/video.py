"""Writing replay frames: MP4 (H.264 through imageio-ffmpeg's bundled ffmpeg), GIF (Pillow)
or a PNG still. A file is written beside its destination and moved into place when
complete, so an interrupted replay never leaves half a video.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from aeromanip.errors import AeromanipError, ConfigError
from aeromanip.viz.dependencies import require

KINDS = {".mp4": "mp4", ".gif": "gif", ".png": "png"}
MIN_SIDE, MAX_SIDE = 16, 4096  # [px] of a panel
GIF_MAX_BYTES = 600e6  # a GIF's frames are held in memory (one byte a pixel) until saved
MP4_QUALITY = 5.5  # imageio-ffmpeg 0..10 scale: libx264 -crf 22 (x264 default 23)
MP4_PRESET = "veryfast"  # x264 preset: encoding stays well below rendering time


def output_kind(path: Path) -> str:
    """``mp4``, ``gif`` or ``png`` from the suffix of ``--out`` (``ConfigError`` otherwise)."""
    kind = KINDS.get(Path(path).suffix.lower())
    if kind is None:
        raise ConfigError(
            f"--out {path}: unknown suffix {Path(path).suffix!r} (allowed: .mp4, .gif, .png)"
        )
    return kind


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> ``(640, 480)``: even numbers in [16, 4096] (H.264 needs even sides)."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(text))
    return check_size((int(m[1]), int(m[2])) if m else None, text)


def check_size(size: object, text: object = None) -> tuple[int, int]:
    """``size`` as ``(width, height)`` if both are even integers in [16, 4096], else a
    ``ConfigError`` quoting ``text`` (default: ``size``)."""
    ok = (
        isinstance(size, tuple | list)
        and len(size) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) for v in size)
        and all(MIN_SIDE <= v <= MAX_SIDE and v % 2 == 0 for v in size)
    )
    if not ok:
        raise ConfigError(
            f"--size: expected WxH with even W and H in [{MIN_SIDE}, {MAX_SIDE}], "
            f"e.g. 640x480, got {text if text is not None else size!r}"
        )
    return int(size[0]), int(size[1])  # type: ignore[index]


def check_gif(frames: int, width: int, height: int) -> None:
    """A GIF of ``frames`` frames must fit in memory (``ConfigError`` saying what to do)."""
    if frames * width * height > GIF_MAX_BYTES:
        limit = int(GIF_MAX_BYTES // (width * height))
        raise ConfigError(
            f"--out *.gif: {frames} frames of {width}x{height} is too long for a GIF "
            f"(at most {limit}); use .mp4, a higher --speed, a lower --fps or a smaller --size"
        )


class FrameWriter:
    """Write RGB frames (height, width, 3) to ``path`` at ``fps``; a context manager.

    The file appears at ``path`` only when the block ends without an exception.
    """

    def __init__(self, path: Path, width: int, height: int, fps: float) -> None:
        self.path = Path(path)
        self.kind = output_kind(self.path)
        self.size, self.fps, self.frames = (width, height), float(fps), 0
        stem, suffix = self.path.stem, self.path.suffix
        self._tmp = self.path.with_name(f".{stem}.partial-{os.getpid()}{suffix}")
        self._gen: Any = None
        self._gif: list[Any] = []

    def __enter__(self) -> FrameWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.kind == "mp4":
            ffmpeg = require("imageio_ffmpeg", "imageio-ffmpeg", "an MP4 replay")
            self._gen = ffmpeg.write_frames(
                str(self._tmp),
                self.size,
                fps=self.fps,
                quality=MP4_QUALITY,
                macro_block_size=1,
                ffmpeg_log_level="error",
                output_params=["-preset", MP4_PRESET],
            )
            self._gen.send(None)
        else:
            require("PIL.Image", "pillow", f"a {self.kind.upper()} replay")
        return self

    def write(self, frame: np.ndarray) -> None:
        """Append one frame (a PNG keeps only the first)."""
        if frame.shape != (self.size[1], self.size[0], 3):
            raise AeromanipError(
                f"FrameWriter.write: a frame of shape {frame.shape}, expected "
                f"{(self.size[1], self.size[0], 3)} (height, width, 3)"
            )
        if self.kind == "mp4":
            self._gen.send(np.ascontiguousarray(frame))
        elif self.kind == "gif":
            from PIL import Image

            image = Image.fromarray(frame)
            self._gif.append(image.quantize(256, Image.Quantize.FASTOCTREE, dither=0))
        elif self.frames == 0:
            from PIL import Image

            Image.fromarray(frame).save(self._tmp)
        self.frames += 1

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        try:
            if self._gen is not None:
                self._gen.close()
            if exc_type is None and self.kind == "gif" and self._gif:
                self._gif[0].save(
                    self._tmp,
                    save_all=True,
                    append_images=self._gif[1:],
                    loop=0,
                    duration=round(1000.0 / self.fps),
                    optimize=False,
                )
        finally:
            self._gif = []
            if exc_type is None and self._tmp.exists():
                os.replace(self._tmp, self.path)
            else:
                self._tmp.unlink(missing_ok=True)
