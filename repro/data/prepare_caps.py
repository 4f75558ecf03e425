"""Caps on what preparing a declared data set holds in memory (issue 29), checked before it is
allocated; long clips converted in slices; the finiteness check of what is published.

Where the memory went.  Converting one clip of ``T`` frames and ``J`` joints made float64
copies of its (T, J, 4) quaternions and (T, J, 3) translations, roma's temporaries while Euler
angles became quaternions, then (T, J, 3, 3) rotation matrices and forward kinematics' (T, J,
3, 3) world rotations and (T, J, 3) positions: about 500 bytes per frame per joint at the peak
(a 37 MB, 1,000,000-frame BVH took 2 GB), and resampling to a higher rate multiplies the
frames.  Now (a) the caps below count frames and joints from a BVH's header (``Frames:``,
``Frame Time:``, the joints declared) and the spec's ``[frames] resample_to`` before the frame
lines are parsed (:func:`repro.data.bvh.parse_bvh`'s ``check``), and from an AMC's frame count
as it is read; (b) a clip of more than :data:`CHUNK_ABOVE` frame-joints has its rotations
converted (:meth:`repro.data.bvh.Bvh.local_rotations`), resampled and run through forward
kinematics in slices of :data:`CHUNK` frame-joints (the same element-wise arithmetic; smaller
clips, every Bandai-2 batch among them, are converted whole as before); (c) each clip is
scaled, resampled and kept as float32 as soon as it is converted, as the clips stream.
Measured: a clip peaks at about 170 bytes per frame-joint (its bytes and float64 parse
included), and a whole prepare holds about 60 bytes per frame-joint (after resampling), next
to the ~0.3 GB the process needs for itself.  Every cap but :data:`MAX_POSITION_M` can be
changed for one data set by its spec's ``[limits]`` (:data:`OVERRIDES`).  A clip's size in bytes does not bound this (a joint
with no channels costs no byte per frame in the file, and resampling multiplies the frames),
which is why the caps count frames and joints.  Every cap is stated in docs/data.md ("Frames
and memory").
"""

from __future__ import annotations

import numpy as np

from repro.errors import DataError

#: frames of one clip after resampling (200,000 frames: 28 min at 120 fps, 1.9 h at 30 fps)
MAX_CLIP_FRAMES = 200_000
#: frames × joints of one clip, before and after resampling (the larger counts): a clip peaks
#: at about 170 bytes per frame-joint (its bytes, the float64 parse and the sliced conversion),
#: so about 1 GB at the cap (31 joints × 193,000 frames, 27 min at 120 fps: every clip
#: :data:`MAX_CLIP_FRAMES` admits on a CMU-sized skeleton)
MAX_CLIP_JOINT_FRAMES = 6_000_000
#: frames of every clip together, after resampling (26 times bandai2's 384,931)
MAX_TOTAL_FRAMES = 10_000_000
#: frames × joints of every clip together, after resampling (bandai2 declared: 8.5 million; all
#: of CMU at 30 fps, ~1 million frames × 31 joints: 31 million); each is held as float32 (about
#: 60 bytes with its joints and the published arrays) until the set is published: 3 GB
MAX_TOTAL_JOINT_FRAMES = 50_000_000

#: the ``[limits]`` key of a data-set spec that overrides each cap (for this data set only)
OVERRIDES = {"MAX_CLIP_FRAMES": "max_clip_frames",
             "MAX_CLIP_JOINT_FRAMES": "max_clip_joint_frames",
             "MAX_TOTAL_FRAMES": "max_total_frames",
             "MAX_TOTAL_JOINT_FRAMES": "max_total_joint_frames"}

#: a clip of more frames × joints than this has its rotations converted
#: (:meth:`repro.data.bvh.Bvh.local_rotations`), resampled (:func:`resample_clip`) and run
#: through forward kinematics (:func:`joints_f32`) in slices of :data:`CHUNK` frame-joints
#: (their float64 temporaries take some 300 bytes each); smaller clips are converted whole, as
#: before.  The one definition: those functions read both here when they run.
CHUNK_ABOVE = 1 << 19
CHUNK = 1 << 18


def joints_f32(skel, quats: np.ndarray, root: np.ndarray) -> np.ndarray:
    """(T, J, 3) float32 joint positions of one clip (float32 xyzw ``quats``, ``root``) by
    forward kinematics in float64, in slices of frames when the clip is long."""
    from repro.motion.rotations import quat_to_matrix
    from repro.motion.skeleton import forward_kinematics

    def fk(q, r):
        return forward_kinematics(skel, quat_to_matrix(q.astype(np.float64)),
                                  r.astype(np.float64)).astype(np.float32)

    T, J = quats.shape[:2]
    if T * J <= CHUNK_ABOVE:
        return fk(quats, root)
    step = max(1, CHUNK // J)
    out = np.empty((T, J, 3), np.float32)
    for s in range(0, T, step):
        out[s:s + step] = fk(quats[s:s + step], root[s:s + step])
    return out


def resample_clip(quats: np.ndarray, root: np.ndarray, src_fps: float, dst_fps: float):
    """:func:`repro.motion.resample.resample_clip` (slerp / linear, float64 numpy), its slerp
    done in slices of output frames when the clip is long (the same brackets and the same
    element-wise formula)."""
    import roma
    import torch

    from repro.data.timebase import resampled_frames
    from repro.motion import resample

    T, J = quats.shape[:2]
    K = resampled_frames(T, src_fps, dst_fps)
    if max(T, K) * J <= CHUNK_ABOVE:
        return resample.resample_clip(quats, root, src_fps, dst_fps)
    q = roma.quat_normalize(torch.from_numpy(np.ascontiguousarray(quats)))
    i0, i1, w = resample.bracket(T, src_fps, dst_fps)
    out = np.empty((len(w), J, 4), np.float64)
    step = max(1, CHUNK // J)
    for s in range(0, len(w), step):
        a, b = i0[s:s + step], i1[s:s + step]
        wt = torch.as_tensor(w[s:s + step], dtype=q.dtype).reshape(-1, 1).expand(len(a), J)
        out[s:s + step] = resample.slerp(q[a], q[b], wt).numpy()
    return out, resample.resample_linear(root, src_fps, dst_fps)


class FrameBudget:
    """The caps above for one prepare: :meth:`check` each clip from its header (before its
    frames are parsed), which also counts it towards the totals.  ``limits`` (a spec's
    ``[limits]``, :class:`repro.data.dataset_spec.LimitsSpec`) overrides any of them."""

    def __init__(self, resample_to: float | None, fps: float | None, limits=None):
        self.resample_to = resample_to
        self.fps = fps
        self.frames = 0
        self.joint_frames = 0
        #: cap name -> (value, where it comes from: the constant or the spec's key)
        self.caps: dict[str, tuple[int, str]] = {}
        for name, key in OVERRIDES.items():
            own = None if limits is None else getattr(limits, key, None)
            self.caps[name] = (int(own), f"the spec's [limits] {key}") if own is not None else (
                int(globals()[name]), f"prepare_caps.{name}; raise it for this data set with "
                f"[limits] {key} in the spec")

    def frames_after(self, n_frames: int, src_fps: float) -> int:
        """Frames of a clip of ``n_frames`` at ``src_fps`` after the spec's resampling (the
        rate prepare resamples from: the spec's ``fps``, else the files' rounded to 0.001)."""
        from repro.data.timebase import resampled_frames

        src = self.fps if self.fps is not None else round(src_fps, 3)
        dst = self.resample_to
        if dst is None or abs(dst - src) <= 1e-9:
            return n_frames
        return resampled_frames(n_frames, src, dst)

    def check(self, label: str, n_frames: int, src_fps: float, n_joints: int, *,
              count: bool = True) -> None:
        """Refuse the clip ``label`` (a DataError naming it) when it breaks a cap; with
        ``count``, add it to the totals."""
        out = self.frames_after(n_frames, src_fps)
        how = (f"{out:,} frames after resampling to {self.resample_to:g} fps ({n_frames:,} at "
               f"{src_fps:g} fps)" if out != n_frames else f"{n_frames:,} frames")
        fix = "lower [frames] resample_to or split the clip" if out > n_frames else \
            "split the clip"
        cap, where = self.caps["MAX_CLIP_FRAMES"]
        if out > cap:
            raise DataError(f"{how}; a clip may have at most {cap:,} ({where}): {fix}", label)
        jf = max(n_frames, out) * n_joints
        cap, where = self.caps["MAX_CLIP_JOINT_FRAMES"]
        if jf > cap:
            raise DataError(f"{how} of {n_joints:,} joints make {jf:,} frame-joints to convert; "
                            f"a clip may have at most {cap:,}, about {cap * 170 / 1e9:.2g} GB of "
                            f"memory ({where}): {fix}", label)
        frames, joint_frames = self.frames + out, self.joint_frames + out * n_joints
        for total, name, what in ((frames, "MAX_TOTAL_FRAMES", "frames"),
                                  (joint_frames, "MAX_TOTAL_JOINT_FRAMES", "frame-joints")):
            cap, where = self.caps[name]
            if total > cap:
                raise DataError(f"the clips read up to this one hold {total:,} {what} (after "
                                f"resampling); a data set may have at most {cap:,} ({where}): "
                                "resample to a lower rate or split the data set", label)
        if count:
            self.frames, self.joint_frames = frames, joint_frames


#: largest position (metres) a prepared clip may hold, root or joint: a capture volume is
#: metres wide, and squares of larger float32 positions (distances, FID) soon overflow
MAX_POSITION_M = 1e5


def check_finite(label: str, **arrays: np.ndarray) -> None:
    """Refuse a converted clip whose arrays (as they will be stored) hold a NaN or an infinity:
    a position of 1e300 is finite in float64 and infinite once stored as float32 (issue 29;
    :func:`repro.data.cache.first_non_finite`, as :func:`repro.data.cache.write_cache` checks).
    Positions (``root``, ``joints``) must also be within :data:`MAX_POSITION_M`."""
    from repro.data.cache import first_non_finite

    for what, a in arrays.items():
        found = first_non_finite(a)
        if found is not None:
            count, frame = found
            raise DataError(f"{count:,} non-finite value(s) in its {what} (first at "
                            f"frame {frame + 1}) once stored as {a.dtype}: values too large for "
                            "float32, or NaN; nothing was published", label)
        if what != "rotations" and a.size and float(np.abs(a).max()) > MAX_POSITION_M:
            frame = int(np.argwhere(np.abs(a) > MAX_POSITION_M)[0][0])
            raise DataError(f"its {what} reach {float(np.abs(a).max()):.3g} m (first at frame "
                            f"{frame + 1}); positions over {MAX_POSITION_M:g} m (prepare_caps."
                            "MAX_POSITION_M) are refused: check [skeleton] units", label)
