"""The estimate store: stdlib SQLite in WAL mode, one transaction per update batch.

Tables:

- ``meta``: schema version, the profile's fingerprint and name, creation time;
- ``estimates``: the current value, std, validity, stage, status and sample count
  of each parameter (one row each, replaced per batch);
- ``history``: a row per parameter whenever its estimate changed, for
  ``GET /estimates/history``; bounded by pruning the oldest rows;
- ``drives``: one row per drive (an ignition cycle, a service run, or a stretch between two
  long silences of the bus): when, the estimates it started from and ended with, its own mass
  and wheel-speed scale measures, and its bus print (the CAN ids seen and their periods);
- ``changes``: each change named between drives (vdp.core.change): which, how large, when,
  the parameters it reset and their values before.

``drives`` and ``changes`` are added to a store of an earlier vdp when it is opened (the
schema version stays 1: an older vdp ignores them).

A store belongs to one vehicle profile (its fingerprint) and one schema
version.  Opening it with another raises :class:`StoreError` and leaves the
file alone: mixing another car's estimates in would be wrong, and deleting
the user's data silently would be worse.

A damaged store (SQLite reports corruption, or its quick check fails, say a
page overwritten in the middle or the meta table's index broken) is moved
aside, kept under ``NAME.damaged-<UTC time>``, and a fresh store starts;
``recovered`` says what happened.  Damage found later, by a query or a commit
of the running service, raises :class:`StoreDamaged`; :meth:`Store.recover`
then does the same as at open.  A full disk or an I/O error is a

The package: ``estimates`` (:class:`Store`: its life, the estimates and their history),
``schema`` (opening: the tables created, or checked to be this profile's and this schema's, and
those added since), ``drives`` (the meta, drives and changes rows), ``damage`` (SQLite's errors
told apart, and a damaged file moved aside for a fresh one).
"""

from __future__ import annotations

from .damage import is_damage
from .estimates import Store, Stored
from .schema import SCHEMA_VERSION, profile_fingerprint

__all__ = ["SCHEMA_VERSION", "Store", "Stored", "is_damage", "profile_fingerprint"]
