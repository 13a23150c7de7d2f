"""Static files over HTTP, for every server of the project.

* :data:`CONTENT_SECURITY_POLICY` — the policy every page we serve carries.
"""

from __future__ import annotations

# The Content-Security-Policy of every page we serve (renderer, live viewer, study): scripts, styles,
# data and sockets from the serving origin only ('self'; in Chromium it covers ws:// to the same
# host), embedded images/buffers as data: or blob: URLs. A crafted avatar or page cannot make the
# browser reach anything else. Inline scripts are allowed: the pages' import maps and render loops
# are inline, and nothing a user supplies is ever put into a page.
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; media-src 'self' data: blob:; connect-src 'self' data: blob:; "
    "font-src 'self' data:; worker-src 'self' blob:; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'"
)
