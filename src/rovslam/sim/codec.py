"""Video compression artefacts: an H.264 round trip (libx264 through PyAV), frame by frame.

A real ROV camera often reaches the surface as an H.264 stream: blocks, smeared fine
texture, and motion-compensated residue that moves with the previous frames, at the
quality a tether's bandwidth allows. :class:`H264RoundTrip` encodes each rendered frame and
decodes it again. It keeps the encoder's state between frames (that is what makes the
artefacts temporal), so it lives in :func:`rovslam.sim.simulate`'s frame loop, not in the
pure renderer. Settings that keep a simulation reproducible and a longer run's first
frames identical to a shorter run's: one thread, no B-frames, no look-ahead
(``tune=zerolatency``): frame k depends on frames 0..k only, and the same frames give the
same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from rovslam.errors import SimulationError


@dataclass(frozen=True)
class H264Params:
    """Quality of the stream: constant rate factor (0 lossless .. 51 worst), keyframe interval, speed preset."""

    crf: int = 28
    keyframe_interval_s: float = 2.0
    preset: str = "veryfast"

    def __post_init__(self) -> None:
        if not (0 <= self.crf <= 51):
            raise SimulationError(f"H264Params.crf must be in 0..51, got {self.crf}")
        if not self.keyframe_interval_s > 0:
            raise SimulationError(f"H264Params.keyframe_interval_s must be > 0, got {self.keyframe_interval_s}")
        presets = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow")
        if self.preset not in presets:
            raise SimulationError(f"H264Params.preset must be one of {', '.join(presets)}, got {self.preset!r}")


class H264RoundTrip:
    """Encode frames to H.264 and decode them again, in order: :meth:`push` one, get it back degraded.

    ``(H, W, 3) uint8`` RGB in, the same shape out (even sizes; 4:2:0 chroma, so colour
    edges soften as in a real stream). With these settings the decoder returns each frame
    as soon as it is pushed; :meth:`push` checks that and raises SimulationError otherwise.
    """

    def __init__(self, width_px: int, height_px: int, frame_rate_hz: float, params: H264Params | None = None) -> None:
        import av

        if width_px % 2 or height_px % 2:
            raise SimulationError(f"H.264 needs even image sizes, got {width_px}x{height_px}")
        p = params if params is not None else H264Params()
        rate = Fraction(frame_rate_hz).limit_denominator(1000)
        enc = av.CodecContext.create("libx264", "w")
        enc.width, enc.height = width_px, height_px
        enc.pix_fmt = "yuv420p"
        enc.time_base = 1 / rate
        enc.framerate = rate
        enc.thread_count = 1
        enc.options = {
            "crf": str(p.crf),
            "preset": p.preset,
            "tune": "zerolatency",
            "bf": "0",
            "g": str(max(1, int(round(p.keyframe_interval_s * frame_rate_hz)))),
            "threads": "1",
        }
        dec = av.CodecContext.create("h264", "r")
        dec.thread_count = 1
        self._enc, self._dec = enc, dec
        self._shape = (height_px, width_px, 3)
        self._pts = 0

    def push(self, rgb: np.ndarray) -> np.ndarray:
        """The frame ``rgb`` after the encoder and the decoder: ``(H, W, 3) uint8``."""
        import av

        if rgb.shape != self._shape or rgb.dtype != np.uint8:
            raise SimulationError(f"H.264 round trip expects {self._shape} uint8 frames, got {rgb.shape} {rgb.dtype}")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts = self._pts
        self._pts += 1
        out = []
        for packet in self._enc.encode(frame):
            out.extend(self._dec.decode(packet))
        if len(out) != 1:
            raise SimulationError(f"the H.264 round trip returned {len(out)} frames for one (expected 1)")
        return out[0].to_ndarray(format="rgb24")

    def close(self) -> None:
        """Flush the encoder (nothing is pending with these settings) and drop the codecs."""
        self._enc.encode(None)
        self._enc = self._dec = None  # type: ignore[assignment]
