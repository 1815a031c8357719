"""The operator's error tree: permanent (fix the input) versus transient (retry).

Only the kopf edge maps these to ``kopf.PermanentError``/``TemporaryError``;
the core raises these so it never depends on kopf.
"""

from __future__ import annotations


class OperatorError(Exception):
    """Base of every error the operator raises on purpose."""


class PermanentError(OperatorError):
    """Bad input or configuration: retrying cannot help, the message says what to fix."""


class TransientError(OperatorError):
    """The world moved or the API server hiccupped: the next reconcile retries."""


class Conflict(TransientError):
    """A resourceVersion precondition failed: someone else wrote first."""


class AlreadyExists(TransientError):
    """A create found an object of that name: someone (this operator before a crash?) made it first."""


class NotFound(TransientError):
    """The object vanished between the snapshot and the write."""


class StoreError(TransientError):
    """The object store of job outputs refused or did not answer: the next pass tries again."""


class ResourceMissing(OperatorError):
    """A CRD the operator needs is not installed (deleted, or not yet applied): back off, retry."""


class ResourcesReplaced(OperatorError):
    """The CRDs were deleted and created again: kopf's watches must be started afresh."""
