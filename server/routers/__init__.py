"""REST routers, mounted under /v1 by :func:`server.app.create_app`."""
