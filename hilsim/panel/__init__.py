"""The browser control panel (``hilsim panel``, ``hilsim run --panel``): docs/panel.md.

A process of its own: it reads the show's state feed and sends its commands over the local
socket of :mod:`hilsim.show.feed`, and serves the page and its WebSocket to browsers with
the ``websockets`` package (the ``panel`` extra). Nothing here imports the show: the tick
never waits on a browser. :mod:`hilsim.panel.server` is the server and its guards,
:mod:`hilsim.panel.runs` the past runs, ``page.html`` the page (our own HTML, CSS and JS).
"""
