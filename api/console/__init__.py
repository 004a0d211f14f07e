"""The operator console: server-rendered pages (Jinja2) made live with htmx and server-sent events.

Served by ``fleetbus api`` under ``/console/`` (``/`` leads there), with the same accounts, roles
and login limits as the HTTP API. Every script and style it uses is served from
``static/`` (htmx vendored with its licence), under a Content-Security-Policy that allows no
inline script and nothing from elsewhere.
"""
