"""Writing a copy of a bag with some image messages replaced, through ``rosbags``.

:class:`BagCopy` receives every message of the source bag (a
:class:`~lenspair.capture.frame_types.BagMessage`, in log-time order) and writes it
to a new bag of the same kind: a ROS 1 ``.bag`` for a ``.bag``, a ROS 2 bag
folder with the same storage (``sqlite3`` for ``.db3``, ``mcap`` for
``.mcap``) for a ROS 2 input. Every connection is copied with its message
definition, md5/type hash, caller id, latching and QoS profiles, and every
message keeps its log time; messages that are not replaced are copied byte for
byte. A replaced image keeps its header (stamp, frame id), size and encoding:
only the pixel payload changes (:func:`encode_image`; a Bayer frame, restored
in RGB, is sampled back into its mosaic, a ``yuv422`` one is packed back by
OpenCV, and an ``rgba8``/``bgra8`` frame keeps its recorded alpha). With a ``suffix``, the
restored image goes to ``<topic><suffix>`` and the original stays on
``<topic>``.

Bag-level compression of the source is not reproduced (the copy is
uncompressed); per-message compression (``CompressedImage``) is.
"""

from dataclasses import replace
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
from rosbags.interfaces import MessageDefinitionFormat
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import (
    Stores,
    TypesysError,
    get_types_from_idl,
    get_types_from_msg,
    get_typestore,
)

from lenspair.capture.errors import CaptureError
from lenspair.capture.frame_types import BagMessage
from lenspair.capture.image_messages import (
    COMPRESSED_IMAGE,
    YUV422_CONVERSIONS,
    bayer_pattern,
    colour_order,
    compressed_mosaic,
    raw_alpha,
)
from lenspair.capture.recording_types import active_bag_stem, is_ros1_bag
from lenspair.capture.rosbag import storage_suffix

_IDL_SEPARATOR = "=" * 80 + "\n"


def _definition_hash(msgdef: str, msgtype: str, topic: str, idl: bool = False) -> str:
    """The RIHS01 hash of ``msgtype`` as ``msgdef`` (``.msg`` or IDL text) defines it.

    Computed from the definition itself, as readers check it, so a copy's
    hash always agrees with its definition.

    Raises:
        CaptureError: the definition cannot be parsed, naming the topic.
    """
    try:
        return str(_defined_store(msgdef, msgtype, idl).hash_rihs01(msgtype))
    except (KeyError, TypesysError, IndexError) as exc:
        raise _unreadable_definition(topic, msgtype, exc) from None


def _unreadable_definition(topic: str, msgtype: str, exc: Exception) -> CaptureError:
    return CaptureError(
        f"{topic}: cannot read the message definition of {msgtype} the source stores ({exc})"
    )


def _defined_store(msgdef: str, msgtype: str, idl: bool = False) -> Any:
    """A type store holding ``msgtype`` and its dependencies as ``msgdef`` defines them.

    ``idl``: the bag labels the definition IDL (read whole unless it is in
    sections, as rosbags' writer tells IDL); otherwise it is ``.msg`` text,
    unless it begins as such sections do.

    Raises:
        KeyError, TypesysError, IndexError: ``msgdef`` cannot be parsed.
    """
    store = get_typestore(Stores.EMPTY)
    if msgdef.startswith(_IDL_SEPARATOR + "IDL: "):  # one file per section
        for part in msgdef.split(_IDL_SEPARATOR)[1:]:
            store.register(get_types_from_idl(part.split("\n", 1)[1]))
    elif idl:
        store.register(get_types_from_idl(msgdef))
    else:
        store.register(get_types_from_msg(msgdef, msgtype))
    return store


def output_bag_path(source: Path, out_dir: Path) -> Path:
    """Where the copy of ``source`` goes inside ``out_dir`` (same name; ROS 2 as a folder).

    The copy of a ``run.bag.active`` is ``run.bag``: it is closed and indexed.
    """
    source = Path(source)
    if (stem := active_bag_stem(source)) is not None:
        return out_dir / f"{stem}.bag"
    if source.suffix.lower() == ".bag":
        return out_dir / source.name
    return out_dir / (source.stem if source.is_file() else source.name)


def _storage_plugin(source: Path) -> StoragePlugin:
    """The storage of a ROS 2 bag: MCAP when a storage file is one, else SQLite.

    A bag recorded with ``--compression-mode file`` names its files
    ``run_0.mcap.zstd`` (:func:`~lenspair.capture.rosbag.storage_suffix`; by
    the last suffix alone, an MCAP bag was copied into SQLite).
    """
    source = Path(source)
    files = [source] if source.is_file() else sorted(source.iterdir())
    if any(storage_suffix(file) == ".mcap" for file in files):
        return StoragePlugin.MCAP
    return StoragePlugin.SQLITE3


def is_storage_file(path: Path) -> bool:
    """Whether a file of a ROS 2 bag folder is its storage or metadata, not a file beside it.

    ``metadata.yaml``, ``run.db3`` and its SQLite side files, ``run.mcap``, and
    either compressed by ``--compression-mode file`` (``run.db3.zstd``).
    """
    return path.name == "metadata.yaml" or storage_suffix(path) is not None


class BagCopy:
    """A bag being written as a copy of ``source`` (use as a context manager).

    Args:
        source: the bag read (decides the output kind and storage).
        destination: from :func:`output_bag_path`; must not exist.
        suffix: when set, restored images go to ``<topic><suffix>``, and every
            other image of a chosen camera (judged clean, or failed) goes
            there as recorded: the topic has a message for each frame.
        jpeg_quality: the quality 1-100 of restored JPEG ``CompressedImage``
            messages (``None``: OpenCV's default, 95); see :func:`encode_image`.
    """

    def __init__(
        self,
        source: Path,
        destination: Path,
        suffix: str = "",
        jpeg_quality: int | None = None,
    ) -> None:
        self.ros1 = is_ros1_bag(Path(source))
        self.jpeg_quality = jpeg_quality
        self.typestore = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        self.suffix = suffix
        self.writer: Any = (
            Writer1(destination)
            if self.ros1
            else Writer2(destination, version=9, storage_plugin=_storage_plugin(source))
        )
        self.connections: dict[tuple[int, str], Any] = {}
        self.stores: dict[tuple[str, str], Any] = {}
        """Type stores by (type, definition) that re-serialise restored images (:meth:`_store`)."""
        self.undefined: list[str] = []
        """Topics whose type neither the source nor the type store defines (copied as bytes)."""

    def __enter__(self) -> "BagCopy":
        self.writer.open()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.writer.close()

    def _connection(self, connection: Any, topic: str) -> Any:
        key = (int(connection.id), topic)
        if key not in self.connections:
            if self.ros1:
                self.connections[key] = self.writer.add_connection(
                    topic,
                    connection.msgtype,
                    msgdef=connection.msgdef.data,
                    md5sum=connection.digest,
                    callerid=getattr(connection.ext, "callerid", None),
                    latching=getattr(connection.ext, "latching", None),
                )
            else:
                msgdef, digest = self._definition(connection, topic)
                self.connections[key] = self.writer.add_connection(
                    topic,
                    connection.msgtype,
                    msgdef=msgdef,
                    rihs01=digest,
                    serialization_format=getattr(connection.ext, "serialization_format", "cdr"),
                    offered_qos_profiles=getattr(connection.ext, "offered_qos_profiles", []),
                )
        return self.connections[key]

    def _definition(self, connection: Any, topic: str) -> tuple[str, str]:
        """The message definition and RIHS01 hash to write for a ROS 2 connection.

        The source's own where it stores both. A ROS 2 Humble bag stores
        neither, and a bare ``.mcap`` no hash: the definition then comes from
        the ROS 2 type store and the hash from the definition, so that the two
        agree (readers check; a copy with empty definitions beside the type
        store's hashes could not be opened). A type the store does not know
        either (a vendor's message in a Humble bag) is copied under its name
        with an empty definition (and that definition's hash: the writer needs
        one), which no reader can decode it by; :attr:`undefined` lists its topic.
        """
        msgtype = connection.msgtype
        msgdef, digest = connection.msgdef.data, connection.digest
        idl = connection.msgdef.format == MessageDefinitionFormat.IDL
        if msgdef and digest:
            return msgdef, digest
        if not msgdef:
            idl = False
            try:
                msgdef = self.typestore.generate_msgdef(msgtype, ros_version=2)[0]
            except (KeyError, TypesysError):  # rosbags' words for a type it does not know
                self.undefined.append(f"{topic} ({msgtype})")
                msgdef = ""
        if not digest:
            digest = _definition_hash(msgdef, msgtype, topic, idl)
        return msgdef, digest

    def _store(self, connection: Any) -> Any:
        """The type store a restored image of ``connection`` is serialised with.

        The one its reader decoded it with: the definition the source stores
        for the topic, where it stores one, else the stock ROS type store. A
        driver's ``sensor_msgs/Image`` with a field of its own (an exposure
        time after ``data``) was written by the stock definition, without
        that field, and the copy's messages could not be read.

        Raises:
            CaptureError: the stored definition cannot be parsed, naming the topic.
        """
        msgdef, msgtype = str(connection.msgdef.data or ""), str(connection.msgtype)
        if not msgdef:
            return self.typestore
        if (msgtype, msgdef) not in self.stores:
            try:
                idl = connection.msgdef.format == MessageDefinitionFormat.IDL
                self.stores[msgtype, msgdef] = _defined_store(msgdef, msgtype, idl)
            except (KeyError, TypesysError, IndexError) as exc:
                raise _unreadable_definition(connection.topic, msgtype, exc) from None
        return self.stores[msgtype, msgdef]

    def write(self, item: BagMessage, restored: np.ndarray | None = None) -> None:
        """Copy ``item``; with ``restored`` pixels, write them as its image too.

        Raises:
            CaptureError: the restored image cannot be encoded in the
                message's encoding.
        """
        original = self._connection(item.connection, item.connection.topic)
        if restored is None:
            self.writer.write(original, item.log_time_ns, item.raw)
            if self.suffix and item.frame is not None:  # a chosen camera's frame left as is
                target = self._connection(item.connection, item.connection.topic + self.suffix)
                self.writer.write(target, item.log_time_ns, item.raw)
            return
        message = encode_image(item.connection.msgtype, item.message, restored, self.jpeg_quality)
        msgtype = item.connection.msgtype
        store = self._store(item.connection)
        data = (
            store.serialize_ros1(message, msgtype)
            if self.ros1
            else store.serialize_cdr(message, msgtype)
        )
        if self.suffix:
            self.writer.write(original, item.log_time_ns, item.raw)
            target = self._connection(item.connection, item.connection.topic + self.suffix)
            self.writer.write(target, item.log_time_ns, data)
        else:
            self.writer.write(original, item.log_time_ns, data)


def mosaic(image: np.ndarray, pattern: str) -> np.ndarray:
    """An RGB image sampled into the Bayer ``pattern`` (``rggb``...): one channel a pixel.

    What a restored frame of a Bayer camera is written back as: each pixel
    keeps the colour its site of the mosaic records.
    """
    channel = {"r": 0, "g": 1, "b": 2}
    out = np.empty(image.shape[:2], dtype=image.dtype)
    for index, colour in enumerate(pattern):
        row, col = divmod(index, 2)
        out[row::2, col::2] = image[row::2, col::2, channel[colour]]
    return out


_SIGNATURES = {b"\x89PNG": ".png", b"\xff\xd8": ".jpg", b"II*\x00": ".tif", b"MM\x00*": ".tif"}
"""How a ``CompressedImage`` payload begins, by the codec that wrote it."""


def compressed_codec(fmt: str, payload: Any) -> str:
    """The codec (``.png``, ``.jpg``, ``.tif``) to write a ``CompressedImage`` back in.

    The one its recorded payload was written in, told by its first bytes: the
    ``format`` field is free text (empty, ``mono16; tiff``), and choosing by
    whether it says "png" wrote a 16-bit PNG or TIFF back as an 8-bit JPEG
    (OpenCV clips the samples with a warning, not an error). A payload of no
    known signature falls back to the field: PNG when it says so, else JPEG.
    """
    head = bytes(payload[:4]) if isinstance(payload, bytes) else bytes(np.asarray(payload)[:4])
    for signature, extension in _SIGNATURES.items():
        if head.startswith(signature):
            return extension
    return ".png" if "png" in str(fmt).lower() else ".jpg"


def encode_image(
    msgtype: str, message: Any, image: np.ndarray, jpeg_quality: int | None = None
) -> Any:
    """A copy of an image message with ``image`` as its pixels; header and encoding kept.

    Args:
        msgtype: ``sensor_msgs/msg/Image`` or ``sensor_msgs/msg/CompressedImage``.
        message: the deserialised original.
        image: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)`` RGB, the
            original's size and dtype.
        jpeg_quality: the quality 1-100 a ``CompressedImage`` of a JPEG format is
            encoded at (``None``: OpenCV's default, 95); a PNG's (lossless) and
            raw images are unaffected.

    Raises:
        CaptureError: an encoding that cannot hold ``image`` (colour for a
            ``mono8`` message, 16 bits for a JPEG), or an ``rgba8``/``bgra8``
            original whose alpha cannot be read.
    """
    if msgtype == COMPRESSED_IMAGE:
        extension = compressed_codec(message.format, message.data)
        if extension == ".jpg" and image.dtype != np.uint8:
            raise CaptureError(
                f"cannot write a {image.dtype} image as JPEG (format {message.format!r})"
            )
        pattern = compressed_mosaic(message.format)
        if image.ndim == 3 and pattern is not None:
            image = mosaic(image, pattern)  # back into the mosaic the payload held
        pixels = image if image.ndim == 2 else np.ascontiguousarray(image[:, :, ::-1])
        params = (
            [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality]
            if extension == ".jpg" and jpeg_quality is not None
            else []
        )
        ok, encoded = cv2.imencode(extension, pixels, params)
        if not ok:
            raise CaptureError(f"cannot encode a {image.dtype} image as {extension}")
        return replace(message, data=np.asarray(encoded, dtype=np.uint8).reshape(-1))
    encoding = str(message.encoding).lower()
    if image.ndim == 3 and (bayer := bayer_pattern(encoding)) is not None:
        image = mosaic(image, bayer[0])  # back into the camera's own mosaic
    if image.ndim == 3 and encoding in YUV422_CONVERSIONS:
        image = cv2.cvtColor(np.ascontiguousarray(image), YUV422_CONVERSIONS[encoding][1])
    elif image.ndim == 3:
        order = colour_order(encoding)
        if order is None:
            raise CaptureError(f"cannot write restored pixels as encoding {message.encoding!r}")
        image = image[:, :, list(order)]
        alpha = raw_alpha(message, f"the original {message.encoding} message")
        if alpha is not None:  # rgba8/bgra8: the colour restored, the alpha as recorded
            image = np.dstack([image, alpha])
    little = np.ascontiguousarray(image, dtype=image.dtype.newbyteorder("<"))
    row_bytes = little.shape[1] * (1 if little.ndim == 2 else little.shape[2])
    row_bytes *= little.dtype.itemsize
    return replace(
        message,
        is_bigendian=0,
        step=row_bytes,
        data=np.frombuffer(little.tobytes(), dtype=np.uint8).copy(),
    )
