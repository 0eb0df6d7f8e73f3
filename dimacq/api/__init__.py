"""The REST API (FastAPI): :func:`create_app` builds an app around a :class:`~dimacq.services.lab.Lab`."""

from dimacq.api.app import create_app

__all__ = ["create_app"]
