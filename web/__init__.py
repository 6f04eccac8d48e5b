"""ippc.web: a read-only live view in the browser, served from the same
process and trio loop as the service it shows (rddl-server, rddl-batch,
rddl-dispatch). No build step, nothing fetched from the internet, no input
that changes anything. docs/web.md is the user's page; this is the API.

Serving (`http.py`)::

    routes = Routes()

    @routes.route("/")
    def index(request: Request) -> Response:
        return Response(page("title", ..., events="/events", nav={"home": "/"}))

    routes.add("/events", lambda r: EventStream(feed, ["overview"], snapshot_fn))

    options = WebOptions.from_cli(web, web_host)       # None: --web not given
    port = await nursery.start(serve_web, routes, options)
    click.echo(f"web view on {web_url(options, port)}")

  A handler is a plain function `Request -> Response | EventStream`
  (`request.params` holds the `{name}` parts of the route, `request.query`
  the query); it reads in-memory state and never waits. Raise
  `HTTPError(404, "...")` (or `not_found(what)`) for an error page.
  `Response(body, status=200, content_type=HTML|SVG|JSON|TEXT)`. `/static/`
  serves live.js and style.css from the package. Only GET and HEAD;
  127.0.0.1 by default (another host is logged as a warning); security
  headers on every response (a CSP without inline scripts: pages carry no
  <script> of their own, live.js does the updating).

The live feed (`feed.py`)::

    feed = Feed()                       # one per service
    feed.publish(event, topic)          # never blocks, never raises
    feed.watched(topic)                 # anyone following? (skip building events)

  An `EventStream(feed, topics, snapshot)` route subscribes a viewer to
  `topics`; `snapshot()` is called at connect time and returns the events
  that draw the whole current picture (the first one should be a
  `rows_event(..., reset=True)`). Each viewer has a bounded queue
  (`Feed(queue_size=256)`); one that falls behind is dropped (its
  connection closed) and its browser reconnects for a fresh snapshot.
  Publish coalesced changes (e.g. twice a second from a task, as
  rddl-server's view does), not one event per simulator step: each event a
  viewer gets costs the loop one send (~0.1-0.4 ms on loopback with 100
  viewers, measured).

Pages and the events live.js applies (`html.py`)::

    h("td", name, class_="c")           # every child and attribute escaped
    esc(x); Markup(...)                 # Markup = trusted HTML made here
    page(title, *body, events="/events", nav={...})
    live_table("sessions", [("id", "session"), ("client", "client"), ...],
               rows=[(key, cells), ...], links={"id": "/session/{key}"},
               charts={"chart": ("/chart/session/{key}.svg", "rounds")},
               limit=None, newest_first=False, state_field="state")
    field("running", 3)                 # a value outside tables
    row_event(table, key, cells); rows_event([(table, key, cells)], reset=True)
    remove_event(table, key); fields_event({"running": 4})

  A row's `state` cell (running/finished/failed...) colours it; a cell
  `cell(text, state=..., href="/path")` carries its own state (it colours
  that cell alone) and a link to a path of the view. A chart
  cell is an <img> of an SVG the server draws; live.js reloads it when the
  cell named by its version field changes.

`to_json(value)` is the JSON a page serves (no `<`, `>`, `&` in its bytes).

Charts (`chart.py`): `sparkline(values)` and `line_chart({name: values},
title=..., x_label=..., y_label=...)` return SVG (`Markup`, names escaped);
serve them with `Response(svg, content_type=SVG)`.

Options (`options.py`): `@web_options` adds `--web PORT` and
`--web-host HOST` to a click command; `WebOptions.from_cli(web, web_host)`
validates them.
"""

from __future__ import annotations

from .chart import line_chart, sparkline
from .feed import Feed, Subscription, encode_event, to_json
from .html import (
    Markup,
    cell,
    esc,
    field,
    fields_event,
    fmt_number,
    h,
    join,
    live_table,
    page,
    remove_event,
    row_event,
    rows_event,
)
from .http import (
    HTML,
    JSON,
    SVG,
    TEXT,
    EventStream,
    HTTPError,
    Request,
    Response,
    Routes,
    WebServer,
    not_found,
    serve_web,
)
from .options import WebOptions, web_options


def web_url(options: WebOptions, port: int) -> str:
    """The address to open in a browser."""
    host = options.host
    if host in ("0.0.0.0", "::"):
        host = "127.0.0.1"
    return f"http://{f'[{host}]' if ':' in host else host}:{port}/"


__all__ = [
    "HTML",
    "JSON",
    "SVG",
    "TEXT",
    "EventStream",
    "Feed",
    "HTTPError",
    "Markup",
    "Request",
    "Response",
    "Routes",
    "Subscription",
    "WebOptions",
    "WebServer",
    "encode_event",
    "cell",
    "esc",
    "field",
    "fields_event",
    "fmt_number",
    "h",
    "join",
    "line_chart",
    "live_table",
    "not_found",
    "page",
    "remove_event",
    "row_event",
    "rows_event",
    "serve_web",
    "sparkline",
    "to_json",
    "web_options",
    "web_url",
]
