"""Scene edges across the frames of a sequence: a segment of one frame continues the track of the segment of the
previous frame that lies on about the same line (direction, polarity, offset) and overlaps it. The error model counts
a track once, however many frames see it (near-identical frames of a hovering camera do not count one curved edge
many times), and how far tracks travel says whether the frames move at all: a lens's field is fixed in the image, a
scene edge's own curvature moves with it, so only frames that move can tell the two apart."""
from __future__ import annotations

import numpy as np

from appdgen.detect.edges import EdgePoints

MAX_ANGLE = 3.0  # degrees between the two segments' normals
MAX_OFFSET = 4.0  # px: each centre from the other's line
MAX_SLIDE = 0.5  # of the longer segment: centres' distance along the line


def link(prev: EdgePoints, cur: EdgePoints) -> np.ndarray:
    """(cur.segments,) index of the previous frame's segment each current one continues, −1 where none."""
    out = np.full(cur.segments, -1)
    if prev.segments == 0 or cur.segments == 0:
        return out
    cos = cur.normal @ prev.normal.T  # same polarity: normals agree in sign
    delta = cur.centre[:, None, :] - prev.centre[None, :, :]
    off_cur = np.abs(np.einsum("ijk,ik->ij", delta, cur.normal))
    off_prev = np.abs(np.einsum("ijk,jk->ij", delta, prev.normal))
    along = np.sqrt(np.maximum((delta ** 2).sum(-1) - off_cur ** 2, 0.0))
    longer = np.maximum(cur.length[:, None], prev.length[None, :])
    ok = (cos >= np.cos(np.radians(MAX_ANGLE))) & (off_cur <= MAX_OFFSET) & (off_prev <= MAX_OFFSET) & (
        along <= MAX_SLIDE * longer)
    cost = np.where(ok, off_cur + off_prev + along / np.maximum(longer, 1.0), np.inf)
    for i in np.argsort(cost.min(1)):  # best pairs first, each previous segment continued once
        j = int(np.argmin(cost[i]))
        if np.isfinite(cost[i, j]):
            out[i] = j
            cost[:, j] = np.inf
    return out


def track_ids(frames: list[EdgePoints]) -> list[np.ndarray]:
    """Per frame, each segment's track id (shared by the segments of one scene edge in consecutive frames)."""
    ids, last, fresh = [], None, 0
    for pts in frames:
        cur = np.arange(fresh, fresh + pts.segments)
        if last is not None:
            prev_pts, prev_ids = last
            j = link(prev_pts, pts)
            cur = np.where(j >= 0, prev_ids[np.maximum(j, 0)], cur)
        fresh += pts.segments
        ids.append(cur)
        last = (pts, cur)
    return ids


def travel(frames: list[EdgePoints], ids: list[np.ndarray]) -> float:
    """Median over the sequence's scene edges of how far each edge moves across the image, normal to itself, from
    the first frame it is seen in to the last (px); an edge seen in one frame of several counts as far-moved (it
    left the view or the frames jumped); a single frame gives 0."""
    if len(frames) < 2 or not any(p.segments for p in frames):
        return 0.0
    track = np.concatenate(ids)
    centre = np.vstack([p.centre for p in frames])
    normal = np.vstack([p.normal for p in frames])
    _, first, seen = np.unique(track, return_index=True, return_counts=True)
    _, last_rev = np.unique(track[::-1], return_index=True)
    last = len(track) - 1 - last_rev
    moved = np.abs(np.einsum("ij,ij->i", centre[last] - centre[first], normal[first]))
    return float(np.median(np.where(seen == 1, 2 * MAX_OFFSET * len(frames), moved)))
