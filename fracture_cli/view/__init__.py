"""``fracture view``: a local web page to test a destructible material.

Shows a bake's fragments (materials, interior faces, exploded view), lets the
user click to hit the object with a chosen impulse and threshold (the runtime
projection runs in the page, in ``engines/web/fracture_runtime.js``), and shows
the modes, the fragment graph, collision shapes and the bake report. The server
(:mod:`fracture_cli.view.server`) is the standard library's ``http.server``; the
page uses three.js, copied into ``static/vendor/`` at build time (``make web``).
"""
