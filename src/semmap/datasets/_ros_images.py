"""Decoding of ROS ``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` messages into semmap's arrays.

Colour becomes (H, W, 3) uint8 RGB; depth becomes (H, W) float32 metres with 0 = invalid. Encodings follow ROS's
``sensor_msgs/image_encodings``: colour rgb8, bgr8, rgba8, bgra8, mono8; depth 16UC1 / mono16 (millimetres) and
32FC1 (metres). ``CompressedImage`` carries JPEG or PNG (``image_transport``'s ``compressed``) or, for depth,
``compressedDepth``: a 12-byte header (format int32, two float32 quantisation parameters) before a PNG.
A damaged payload raises :class:`UnreadableFileError` (the frame is skipped); an encoding semmap cannot read raises
:class:`DatasetError` (the whole topic is unusable).
"""

from __future__ import annotations

import struct

import cv2
import numpy as np

from semmap.datasets.base import UnreadableFileError
from semmap.errors import DatasetError

#: ROS depth images in integer encodings store millimetres.
MILLIMETRES_PER_METRE = 1000.0
#: Colour encodings: name -> (channels, OpenCV conversion to RGB or None).
COLOR_ENCODINGS = {
    "rgb8": (3, None),
    "bgr8": (3, cv2.COLOR_BGR2RGB),
    "rgba8": (4, cv2.COLOR_RGBA2RGB),
    "bgra8": (4, cv2.COLOR_BGRA2RGB),
    "mono8": (1, cv2.COLOR_GRAY2RGB),
    "8uc1": (1, cv2.COLOR_GRAY2RGB),
    "8uc3": (3, cv2.COLOR_BGR2RGB),
}
#: Depth encodings: name -> numpy dtype of one pixel.
DEPTH_ENCODINGS = {"16uc1": np.uint16, "mono16": np.uint16, "32fc1": np.float32}
#: Largest image side accepted from a message (a corrupt header must not make us allocate gigabytes).
MAX_SIDE = 16384
#: ``compressedDepth`` header: compression format (0 = PNG, 1 = RVL) and the inverse-depth quantisation a, b.
COMPRESSED_DEPTH_HEADER = struct.Struct("<iff")
PNG_MAGIC = b"\x89PNG"


def _raw_pixels(msg, where: str, dtype, channels: int) -> np.ndarray:
    """The (H, W[, C]) pixel array of a raw ``Image`` message, honouring ``step`` (row padding) and endianness."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if not (0 < h <= MAX_SIDE and 0 < w <= MAX_SIDE):
        raise UnreadableFileError(where, f"image size {w}x{h} is not plausible")
    itemsize = np.dtype(dtype).itemsize
    row = w * channels * itemsize
    if step < row:
        raise UnreadableFileError(where, f"row step {step} B is shorter than a row of {w} pixels ({row} B)")
    data = np.frombuffer(memoryview(msg.data).cast("B"), np.uint8)
    if len(data) < step * h:
        raise UnreadableFileError(where, f"image data has {len(data)} B, {w}x{h} with step {step} needs {step * h}")
    rows = data[: step * h].reshape(h, step)[:, :row]
    order = ">" if int(msg.is_bigendian) else "<"
    pixels = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order) if itemsize > 1 else dtype)
    pixels = pixels.astype(dtype, copy=False)
    return pixels.reshape(h, w, channels) if channels > 1 else pixels.reshape(h, w)


def decode_color(msg, where: str) -> np.ndarray:
    """RGB (H, W, 3) uint8 of an ``Image`` or ``CompressedImage`` message."""
    if hasattr(msg, "format"):
        image = _imdecode(msg.data, where)
        if image.dtype != np.uint8:
            raise DatasetError(f"{where}: compressed colour image is {image.dtype}, expected 8-bit")
        if image.ndim == 2:
            return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    encoding = str(msg.encoding).lower()
    if encoding not in COLOR_ENCODINGS:
        raise DatasetError(f"{where}: colour encoding {msg.encoding!r} is not supported "
                           f"(supported: {', '.join(COLOR_ENCODINGS)})")
    channels, conversion = COLOR_ENCODINGS[encoding]
    pixels = _raw_pixels(msg, where, np.uint8, channels)
    return np.ascontiguousarray(pixels) if conversion is None else cv2.cvtColor(pixels, conversion)


def decode_depth(msg, where: str) -> np.ndarray:
    """Depth (H, W) float32 metres, 0 where invalid, of an ``Image`` or ``CompressedImage`` message."""
    if hasattr(msg, "format"):
        return _decode_compressed_depth(msg, where)
    encoding = str(msg.encoding).lower()
    if encoding not in DEPTH_ENCODINGS:
        raise DatasetError(f"{where}: depth encoding {msg.encoding!r} is not supported "
                           f"(supported: 16UC1 / mono16 in millimetres, 32FC1 in metres)")
    pixels = _raw_pixels(msg, where, DEPTH_ENCODINGS[encoding], 1)
    return _to_metres(pixels)


def _to_metres(pixels: np.ndarray) -> np.ndarray:
    """Millimetre integers or metre floats to float32 metres, 0 for invalid (0, NaN, inf, negative)."""
    if pixels.dtype == np.uint16:
        return pixels.astype(np.float32) / np.float32(MILLIMETRES_PER_METRE)
    depth = pixels.astype(np.float32, copy=True)
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    return depth


def _decode_compressed_depth(msg, where: str) -> np.ndarray:
    """``compressedDepth`` (header + PNG) or a plain 16-bit PNG in a ``CompressedImage``."""
    data = bytes(memoryview(msg.data).cast("B"))
    fmt = str(msg.format)
    encoding = fmt.split(";")[0].strip().lower()
    if "compresseddepth" not in fmt.lower():
        image = _imdecode(data, where)
        if image.ndim != 2 or image.dtype != np.uint16:
            raise DatasetError(f"{where}: compressed depth ({fmt!r}) decodes to {image.dtype} with shape "
                               f"{image.shape}, expected one 16-bit channel in millimetres")
        return _to_metres(image)
    if data[:4] == PNG_MAGIC:  # very old image_transport versions wrote no header
        kind, quant_a, quant_b = 0, 0.0, 0.0
        payload = data
    else:
        if len(data) < COMPRESSED_DEPTH_HEADER.size:
            raise UnreadableFileError(where, f"compressedDepth message of {len(data)} B has no header")
        kind, quant_a, quant_b = COMPRESSED_DEPTH_HEADER.unpack_from(data)
        payload = data[COMPRESSED_DEPTH_HEADER.size:]
    if kind != 0:
        raise DatasetError(f"{where}: compressedDepth format {kind} (RVL) is not supported; record with png")
    image = _imdecode(payload, where)
    if image.ndim != 2 or image.dtype != np.uint16:
        raise UnreadableFileError(where, f"compressedDepth PNG is {image.dtype} {image.shape}, expected 16-bit")
    if encoding in ("16uc1", "mono16"):
        return _to_metres(image)
    if encoding == "32fc1":
        # inverse depth quantisation of image_transport: stored = a / depth + b, 0 = invalid
        if not (np.isfinite(quant_a) and np.isfinite(quant_b)) or quant_a == 0:
            raise UnreadableFileError(where, f"compressedDepth quantisation ({quant_a}, {quant_b}) is not valid")
        stored = image.astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.float32(quant_a) / (stored - np.float32(quant_b))
        depth[(image == 0) | ~np.isfinite(depth) | (depth < 0)] = 0.0
        return depth.astype(np.float32, copy=False)
    raise DatasetError(f"{where}: compressedDepth encoding {encoding!r} is not supported (16UC1 or 32FC1)")


def _imdecode(data, where: str) -> np.ndarray:
    buffer = np.frombuffer(memoryview(data).cast("B"), np.uint8)
    if buffer.size == 0:
        raise UnreadableFileError(where, "compressed image is empty")
    try:
        image = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None:
        raise UnreadableFileError(where, "cannot decode compressed image (corrupt or truncated)")
    return image


def encode_compressed_depth(depth_mm: np.ndarray) -> bytes:
    """``compressedDepth`` payload (PNG format header + 16-bit PNG) of a millimetre image, as image_transport writes
    it for 16UC1; for writing test bags and converting recordings."""
    ok, png = cv2.imencode(".png", np.ascontiguousarray(depth_mm, dtype=np.uint16))
    if not ok:
        raise DatasetError("cannot encode depth as PNG")
    return COMPRESSED_DEPTH_HEADER.pack(0, 0.0, 0.0) + png.tobytes()
