"""Registering an ingest's two views: the homography and what is checked before and after it.

Before the calibration is used, up to :data:`BIT_DEPTH_FRAMES` frame pairs
spread over the recording are read as stored (:func:`sampled_pairs`) to tell
the bits each camera's 16-bit frames use (:func:`recording_bits`) and whether any pair has
the calibration's image sizes (:func:`size_mismatch`). The clean -> obstructed
homography is then estimated from features pooled over up to
``EstimationParams.max_frames`` pairs (:func:`recording_homography`) and cached
in :data:`REGISTRATION_FILE` with a fingerprint of what it was computed from.
A homography that few matches agree with, or that turns the view, is said in
the log (:func:`warn_if_doubtful`).
"""

import contextlib
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from lenspair.capture import ingest_frames as frame_work
from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest_pairs import map_tasks
from lenspair.capture.journal import fingerprint
from lenspair.capture.recording import FrameRef, Recording, load_frame
from lenspair.capture.rigfile import CameraName
from lenspair.core.bitdepth import significant_bits, widen
from lenspair.core.config import to_plain
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import atomic_write_json
from lenspair.core.spread import spread_indices
from lenspair.rectify.registration import EstimationParams, estimate_homography, implausible_turn
from lenspair.rectify.remap import RemapGrid
from lenspair.rectify.rig import StereoRig

log = logging.getLogger(__name__)

REGISTRATION_FILE = "registration.json"
BIT_DEPTH_FRAMES = 32  # frame pairs read to tell the bits 16-bit frames use (~0.3 s)
MIN_INLIER_SHARE = 0.5
"""Below this share of feature matches agreeing with the homography, registration is doubted.

Scenes registered right: 78-91 % (the sample rain, heavy rain, dust and
parallax recordings); a far wall of a perfect checkerboard registered one
period off: 32 %.
"""


SampledPair = list[tuple[FrameRef, np.ndarray]]
"""The readable frames of one sampled frame pair, obstructed first, each with its raw image."""


def sampled_pairs(pairs: list[tuple[FrameRef, FrameRef]]) -> list[SampledPair]:
    """The readable frames of up to 32 frame pairs spread over the recording, read as stored.

    Unreadable frames are passed over: the frame stage reports them.
    """
    sampled = []
    for index in spread_indices(len(pairs), BIT_DEPTH_FRAMES):
        loaded = []
        for frame in pairs[index]:
            with contextlib.suppress(LenspairError):
                loaded.append((frame, load_frame(frame)))
        sampled.append(loaded)
    return sampled


def recording_bits(recording: Recording, sampled: list[SampledPair]) -> dict[CameraName, int]:
    """Each camera's :func:`significant_bits`, told from the sampled pairs (:func:`sampled_pairs`).

    Told per camera: a rig may pair a 16-bit camera with a 12-bit one
    publishing ``mono16``, or a 10-bit with a 12-bit one; one depth for both
    would scale one camera's frames by the other's, leaving input and target
    4 to 16 times apart in brightness. But the depth is told from the
    brightest value, so two cameras of one depth in a dim recording can fall
    either side of a depth's top (12-bit cameras peaking at 1000 and 1050
    read as 10 and 12 bits): where the two cameras' depths differ, the
    sampled pairs decide (:func:`_agreeing_depths`): both at the deeper
    camera's depth when that leaves the two views nearer in brightness. A
    camera whose frames use fewer than 16 bits is said in the log. A frame
    the sample missed that holds more is rejected with that reason, not
    clipped.

    Returns:
        The bits of ``cam0``'s and ``cam1``'s 16-bit frames (16: taken as they are).
    """
    images: dict[CameraName, list[np.ndarray]] = {"cam0": [], "cam1": []}
    for pair in sampled:
        for frame, image in pair:
            images[frame.camera].append(image)
    bits: dict[CameraName, int] = {camera: significant_bits(images[camera]) for camera in images}
    if bits["cam0"] != bits["cam1"]:
        bits = _agreeing_depths(recording, sampled, bits)
    for camera, frames in images.items():
        if bits[camera] < 16:
            log.warning(
                "%s: %s's 16-bit frames hold %d-bit values (none above %d in %d sampled "
                "frames): they are scaled to the full 16-bit range",
                recording.path,
                camera,
                bits[camera],
                (1 << bits[camera]) - 1,
                len(frames),
            )
    return bits


def _agreeing_depths(
    recording: Recording, sampled: list[SampledPair], bits: dict[CameraName, int]
) -> dict[CameraName, int]:
    """``bits`` as told per camera, or both at the deeper one's: whichever the views agree on.

    Each choice widens both cameras' frames of every sampled pair; the one
    whose median ratio of mean brightness (cam0 over cam1) lies nearer 1 is
    kept. Depths 2 bits apart differ 4x in scale, far beyond an exposure
    difference or what the glass changes; with no pair to compare, the per
    camera depths stand.
    """
    shared = max(bits.values())
    both: dict[CameraName, int] = {"cam0": shared, "cam1": shared}
    offsets = {}
    for name, choice in (("per camera", bits), ("shared", both)):
        ratios = []
        for pair in sampled:
            means = {
                frame.camera: float(widen(image, choice[frame.camera]).mean())
                for frame, image in pair
            }
            if len(means) == 2 and min(means.values()) > 0:
                ratios.append(np.log(means["cam0"] / means["cam1"]))
        if not ratios:
            return bits
        offsets[name] = abs(float(np.median(ratios)))
    if offsets["shared"] >= offsets["per camera"]:
        return bits
    lower = min(bits, key=lambda camera: bits[camera])
    log.warning(
        "%s: %s's 16-bit frames peak below %d, as %d-bit values would, but read as %d-bit "
        "like the other camera's they match its brightness (median ratio %.2f, against %.2f "
        "as %d-bit): both are taken as %d-bit (a dim recording)",
        recording.path,
        lower,
        1 << bits[lower],
        bits[lower],
        shared,
        float(np.exp(offsets["shared"])),
        float(np.exp(offsets["per camera"])),
        bits[lower],
        shared,
    )
    return both


def size_mismatch(sampled: list[SampledPair], rig: StereoRig) -> str | None:
    """The first size mismatch when no sampled pair has the calibration's image sizes, else None.

    Checked before the calibration is used: rectifying with a calibration
    stated for another size can fail first, with a message about the
    calibration's edges (1280x720 stated for 720x540 frames) instead of the
    sizes. The rule is the registration stage's: a pair of other sizes among
    usable ones is only rejected, with its reason, by the frame stage; when no
    pair whose two frames are readable has both sizes right, nothing can be
    registered. A sample without a readable pair is left to the registration
    stage, which says why.

    Returns:
        ``size mismatch: <frame> is WxH px, the calibration says WxH`` (the
        registration stage's words), or None.
    """
    first = None
    for pair in sampled:
        if len(pair) < 2:
            continue
        problems = [
            frame_work.size_problem(image, frame, rig.camera(frame.camera).resolution)
            for frame, image in pair
        ]
        mismatch = next((p for p in problems if p is not None), None)
        if mismatch is None:
            return None
        first = first or mismatch
    return first


def _cached_registration(cache: Path, key: str) -> dict[str, Any] | None:
    """The registration ``cache`` holds when it was computed from ``key``'s inputs, else None.

    A file that is not a registration record (not JSON, not an object, a
    field missing or of another kind: damaged, or edited) is said in the log
    and computed again; one of other inputs (its fingerprint differs) is
    simply computed again.
    """
    try:
        cached = json.loads(cache.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        log.warning("%s: cannot be read (%s); computing the registration again", cache, exc)
        return None
    if isinstance(cached, dict) and cached.get("fingerprint") != key:
        return None
    problem = _registration_problem(cached)
    if problem is not None:
        log.warning("%s: %s; computing the registration again", cache, problem)
        return None
    return dict(cached)


def _registration_problem(cached: Any) -> str | None:
    """What makes ``cached`` (parsed JSON) not a registration record, or None."""
    if not isinstance(cached, dict):
        kinds = {list: "a list", str: "a string", bool: "true or false", type(None): "null"}
        kind = kinds.get(type(cached), "a number")
        return f"holds {kind}, not a registration record (a JSON object)"

    def number(value: Any) -> bool:
        return isinstance(value, int | float) and not isinstance(value, bool)

    def count(value: Any) -> bool:
        return number(value) and isinstance(value, int) and value >= 0

    rows = cached.get("matrix")
    if not (
        isinstance(rows, list)
        and len(rows) == 3
        and all(isinstance(row, list) and len(row) == 3 and all(map(number, row)) for row in rows)
        and np.isfinite(np.asarray(rows, dtype=np.float64)).all()
    ):
        return "its 'matrix' is not a 3x3 matrix of numbers"
    for name in ("inliers", "matches"):
        if not count(cached.get(name)):
            return f"its {name!r} is not a count"
    frames = cached.get("frames")
    if not isinstance(frames, dict) or not all(count(n) for n in frames.values()):
        return "its 'frames' is not a table of counts"
    return None


def recording_homography(
    recording: Recording,
    pairs: list[tuple[FrameRef, FrameRef]],
    context: frame_work.Context,
    estimation: EstimationParams,
    workers: int,
    out_dir: Path,
    setup: dict[str, Any],
) -> dict[str, Any]:
    """The recording's homography, from the cache when its fingerprint matches.

    The fingerprint hashes the setup (calibration, side, thresholds,
    version) and the content of the sampled frames, so a rerun reuses the
    exact same matrix and a changed input recomputes it.

    Returns:
        The registration record, as written to ``registration.json``.

    Raises:
        CaptureError: no sampled pair can be registered (the first one's reason).
    """
    chosen = [pairs[i] for i in spread_indices(len(pairs), estimation.max_frames)]
    contents = [(frame_work.content_id(o), frame_work.content_id(c)) for o, c in chosen]
    identity = [[o.t_ns, *content] for (o, _), content in zip(chosen, contents, strict=True)]
    if chosen and all(o == c and not o.startswith("unreadable") for o, c in contents):
        # two cameras never take the same bytes: one camera's images stored twice
        log.warning(
            "%s: the two cameras' files are byte for byte the same in all %d pairs sampled: "
            "one camera's images recorded twice (a driver or topic mix-up)? The pairs show no "
            "anomaly to learn",
            recording.path,
            len(chosen),
        )
    cache_key = fingerprint(
        {"setup": setup, "estimation": to_plain(estimation), "frames": identity}
    )
    cache = out_dir / REGISTRATION_FILE
    cached = _cached_registration(cache, cache_key)
    if cached is not None:
        return cached
    tasks = [frame_work.SampleTask(o, c, estimation) for o, c in chosen]
    samples = list(map_tasks(frame_work.sample, tasks, workers, context, "features"))
    usable = [s for s in samples if s.problem is None]
    if not usable:
        first = samples[0].problem if samples else "no frame of the two cameras could be paired"
        raise CaptureError(f"{recording.path}: no usable frame pair to register: {first}")
    scale = np.float32(1.0 / 255.0)
    views = [
        (s.obstructed * scale, s.clean * scale, context.valid_obstructed, context.valid_clean)
        for s in usable
    ]
    estimate = estimate_homography(views, estimation, context.verify, [s.matches for s in usable])
    registration = {
        "fingerprint": cache_key,
        "matrix": estimate.matrix.tolist(),
        "inliers": estimate.inliers,
        "matches": estimate.matches,
        "rms_px": estimate.rms_px,
        "frames": {str(s.t_ns): n for s, n in zip(usable, estimate.inliers_per_frame, strict=True)},
    }
    atomic_write_json(cache, registration)
    return registration


def warn_if_doubtful(
    recording: Recording, registration: dict[str, Any], calibration_source: str, qa_sheet: Path
) -> None:
    """Say in the log when the homography may be wrong though every check passed.

    Two signs: under :data:`MIN_INLIER_SHARE` of the feature matches agree
    with it (a repetitive scene registered a period off), or it turns the view
    (:func:`lenspair.rectify.registration.implausible_turn`: the calibration is
    likely another rig's).
    """
    share = registration["inliers"] / max(int(registration["matches"]), 1)
    if share < MIN_INLIER_SHARE:
        log.warning(
            "%s: only %.0f%% of the %d feature matches agree with the homography: a "
            "repetitive scene (a checkerboard, a fence, tiles) can register a whole period "
            "off, which the per-frame checks cannot see; look at %s",
            recording.path,
            100 * share,
            registration["matches"],
            qa_sheet,
        )
    matrix = np.asarray(registration["matrix"], dtype=np.float64)
    if (turned := implausible_turn(matrix)) is not None:
        log.warning(
            "%s: the homography from the clean to the obstructed view %s, where rectified "
            "views of one rig differ by a shift: the calibration (%s) is likely not this "
            "rig's (another rig's, or a camera remounted since); check it, or calibrate again",
            recording.path,
            turned,
            calibration_source,
        )


ENLARGED_CLEAN = 1.5
"""A clean view enlarged more than this onto the obstructed view's pixels is warned about."""


def warn_if_enlarged(recording: Recording, clean: CameraName, target: RemapGrid) -> None:
    """Say in the log when the clean view is enlarged onto the obstructed camera's pixels.

    The dataset is sampled at the obstructed camera's scale (its frames are
    what the network restores); a clean camera of lower resolution is then
    enlarged, and its targets are blurrier than the inputs. (A clean camera
    of higher resolution is reduced, low-pass filtered first: no warning.)
    """
    if target.step < 1 / ENLARGED_CLEAN:
        log.warning(
            "%s: the clean camera %s is enlarged %.1fx onto the obstructed camera's pixels "
            "(it has the lower resolution): the targets are blurrier than the inputs, and a "
            "network trained on them learns to blur",
            recording.path,
            clean,
            1 / target.step,
        )
