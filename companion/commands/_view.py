"""``--view [HOST:]PORT`` and ``--mcap FILE``: the options of the Foxglove view, shared by fly, demo and replay.

Parsing imports nothing of the SDK; :func:`open_view` does, and without the ``view`` extra
fails with one line naming it (exit 2, :class:`~companion.view.publisher.ViewUnavailable`).
"""

from __future__ import annotations

import argparse

from companion.commands._argtypes import output_file


def view_endpoint(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` (host default 127.0.0.1; port 0: any free one)."""
    from companion.view.publisher import parse_endpoint

    try:
        return parse_endpoint(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT, got {text!r} ({exc})") from None


def add_view_arguments(p: argparse.ArgumentParser) -> None:
    """Add ``--view`` and ``--mcap`` to a subcommand."""
    p.add_argument("--view", type=view_endpoint, default=None, metavar="[HOST:]PORT",
                   help="serve a live Foxglove view (WebSocket; loopback unless HOST is given) of the vehicle, "
                        "tracks, plan, setpoints and contour of touch (needs the view extra; docs/VIEW.md)")
    p.add_argument("--mcap", type=output_file, default=None, metavar="FILE",
                   help="record the same channels to an MCAP file for Foxglove (needs the view extra)")


def open_view(args: argparse.Namespace, *, threaded: bool, time_offset_s: float = 0.0):
    """The :class:`~companion.view.publisher.ViewPublisher` the options ask for, or None."""
    if getattr(args, "view", None) is None and getattr(args, "mcap", None) is None:
        return None
    from companion.view.publisher import ViewPublisher

    view = ViewPublisher(mcap=args.mcap, server=args.view, threaded=threaded, time_offset_s=time_offset_s)
    if view.server is not None:
        import sys

        host = args.view[0]
        print(f"view: Foxglove WebSocket ws://{host}:{view.port} (open it in Foxglove: Open connection)",
              file=sys.stderr, flush=True)
    return view
