"""The demonstration service (``nonprehensile serve``): FastAPI over PostgreSQL.

Needs the ``service`` extra (FastAPI, uvicorn, psycopg). See ``docs/service.md``.
"""

from nonprehensile.service.app import DEFAULT_MAX_BYTES, ServiceConfig, create_app
from nonprehensile.service.db import create_token, make_pool
from nonprehensile.service.ingest import Registry, Template, load_template

__all__ = ["DEFAULT_MAX_BYTES", "Registry", "ServiceConfig", "Template", "create_app",
           "create_token", "load_template", "make_pool"]
