"""`uwsimnet view`: a local web page of a replayed trace or a live world (docs/view.md).

state.py (the document and its live updates) and links.py (what the channel models say of each link) are
sans-IO, live.py the Zenoh client, server.py the aiohttp server; static/ holds the page (plain HTML, CSS and
JavaScript: no build step, nothing from the network).
"""

DEFAULT_PORT = 8765
"""Where the page is served unless --port / --view-port says otherwise (here, so that the command line of
`uwsimnet run` names it without importing the page's modules)."""
