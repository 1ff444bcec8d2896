"""Temporal filter for a noisy simulator contact stream (thesis section VII, Table I).

A physics engine reports contacts that flicker: a fingertip resting on an object shows
up in one sample and is missing from the next although nothing moved (thesis Table I).
Computing force closure from a single sample then misses fingers and reports false
negatives. The thesis keeps every contact it has seen in a structure and removes it only
after a counter says it has been missing for K consecutive samples; a new sample of a
kept contact replaces its points and normals.

This module is pure numpy: it knows nothing of pybullet. The replay
(`planner.sim.replay`) feeds it one sample per simulation step.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from planner.errors import InputError
from planner.model import Patch

ContactKey = Hashable
"""Identifies one contact, e.g. ``(link_name, body_name)`` as in Table I."""


def _frozen(a, name: str) -> np.ndarray:
    arr = np.array(a, dtype=float, copy=True).reshape(-1, 3)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"contact {name} must be finite, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class FilteredContact:
    """One contact kept by the filter.

    Attributes:
        key: the contact's identity, e.g. ``("index_distal", "object")``.
        points: (n, 3) contact points of its latest sample (frame chosen by the caller).
        normals: (n, 3) unit normals of its latest sample, same frame and order.
        missing: consecutive samples it has been absent from (0 = seen in the last one).
        seen: how many samples it has appeared in since it was (re)created.
    """

    key: ContactKey
    points: np.ndarray
    normals: np.ndarray
    missing: int
    seen: int


class ContactFilter:
    """Counter-based temporal contact filter (thesis section VII).

    A contact enters on its first sample. Every later sample either contains it (its
    points/normals are replaced, its miss counter reset to 0) or not (its counter grows).
    It is removed when the counter reaches ``k_missing``: with ``k_missing=1`` the filter
    is the raw stream.

    Args:
        k_missing: consecutive misses after which a contact is dropped (>= 1).
        relevant: predicate on a key; contacts for which it is False are ignored
            (Table I: "box from base vs ground" is not part of the grasp). Default: all.
    """

    def __init__(self, k_missing: int, relevant: Callable[[ContactKey], bool] | None = None):
        if int(k_missing) != k_missing or k_missing < 1:
            raise InputError(f"k_missing must be an integer >= 1, got {k_missing!r}")
        self.k_missing = int(k_missing)
        self._relevant = relevant
        self._contacts: dict[ContactKey, FilteredContact] = {}
        self.samples = 0

    def reset(self) -> None:
        """Forget every contact (e.g. when the scene is rebuilt)."""
        self._contacts.clear()
        self.samples = 0

    def update(self, sample: Mapping[ContactKey, tuple] | Iterable[tuple]) -> dict[ContactKey, FilteredContact]:
        """Feed one raw sample and return the filtered contact set.

        Args:
            sample: the contacts of one simulator sample, ``{key: (points (n,3), normals (n,3))}``
                or an iterable of ``(key, points, normals)``; one key may appear several
                times in the iterable form, its points are then concatenated.

        Returns:
            ``{key: FilteredContact}`` for every contact currently kept, in first-seen order.
        """
        merged: dict[ContactKey, tuple[list, list]] = {}
        items = sample.items() if isinstance(sample, Mapping) else ((k, (p, n)) for k, p, n in sample)
        for key, (points, normals) in items:
            if self._relevant is not None and not self._relevant(key):
                continue
            pts, nrm = _frozen(points, "points"), _frozen(normals, "normals")
            if pts.shape != nrm.shape:
                raise InputError(f"contact {key!r}: {len(pts)} points but {len(nrm)} normals")
            acc = merged.setdefault(key, ([], []))
            acc[0].append(pts)
            acc[1].append(nrm)

        self.samples += 1
        kept: dict[ContactKey, FilteredContact] = {}
        for key, old in self._contacts.items():
            if key in merged:
                continue
            missing = old.missing + 1
            if missing < self.k_missing:
                kept[key] = FilteredContact(key, old.points, old.normals, missing, old.seen)
        for key, (pts, nrm) in merged.items():
            seen = self._contacts[key].seen + 1 if key in self._contacts else 1
            kept[key] = FilteredContact(key, _frozen(np.vstack(pts), "points"),
                                        _frozen(np.vstack(nrm), "normals"), 0, seen)
        # keep first-seen order stable for reproducible outputs
        order = [k for k in self._contacts if k in kept] + [k for k in kept if k not in self._contacts]
        self._contacts = {k: kept[k] for k in order}
        return dict(self._contacts)

    @property
    def contacts(self) -> dict[ContactKey, FilteredContact]:
        """The contacts currently kept, ``{key: FilteredContact}``."""
        return dict(self._contacts)

    def patches(self, group: Callable[[ContactKey], str | None]) -> dict[str, Patch]:
        """Group the kept contacts into closure patches.

        Args:
            group: maps a contact key to a patch name (e.g. link -> finger); None skips it.

        Returns:
            ``{name: Patch}`` with all points of the contacts in that group, the form
            `planner.closure.grasp_closure` takes; each point's link is its contact's key
            (so the "link" contact model gives every contact key its own contact).
        """
        acc: dict[str, tuple[list, list, list]] = {}
        for key, c in self._contacts.items():
            name = group(key)
            if name is None:
                continue
            a = acc.setdefault(name, ([], [], []))
            a[0].append(c.points)
            a[1].append(c.normals)
            a[2].extend([key] * len(c.points))
        return {name: Patch(np.vstack(p), np.vstack(n), links) for name, (p, n, links) in acc.items()}
