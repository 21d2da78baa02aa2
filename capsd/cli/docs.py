"""`capsd docs figures`: README tables from the benches' JSON."""

from __future__ import annotations

import argparse
from pathlib import Path

from capsd.cli.common import Subcommands, fail
from capsd.errors import CapsdError
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_FAILURE,
    EXIT_OK,
)


def _cmd_docs_figures(args: argparse.Namespace) -> int:
    from capsd.readme_figures import blocks, render

    try:
        text = args.file.read_text()
        new = render(text, root=args.file.resolve().parent)
    except OSError as exc:
        return fail(f"docs figures: {args.file}: {exc}", EXIT_CONFIG)
    except CapsdError as exc:
        return fail(f"docs figures: {args.file}: {exc}", EXIT_CONFIG)
    found = blocks(text)
    if args.check:
        if new != text:
            return fail(
                f"docs figures: {args.file} is not up to date with its figures' JSON "
                "(run `capsd docs figures`)",
                EXIT_FAILURE,
            )
        print(f"{args.file}: {len(found)} figure blocks up to date")
        return EXIT_OK
    args.file.write_text(new)
    print(f"{args.file}: {len(found)} figure blocks written ({', '.join(n for n, _ in found)})")
    return EXIT_OK


def register(sub: Subcommands) -> None:
    """Add the docs verbs to the `capsd` parser's subcommands."""
    docs = sub.add_parser(
        "docs",
        help="the README's figures: tables written from the benches' JSON",
        description="Documentation written by commands, never by hand.",
    )
    docs_sub = docs.add_subparsers(dest="docs_command", required=True, metavar="WHAT")
    dfig = docs_sub.add_parser(
        "figures",
        help="rewrite the tables between `<!-- figures: NAME JSON -->` markers",
        description="Each block names a table and the bench JSON it comes from (docs/figures/); "
        "the block is rewritten from that JSON with a line naming the bench's command. "
        "--check: exit 1 when the file is not up to date.",
    )
    dfig.add_argument("--file", type=Path, default=Path("README.md"), help="Markdown file")
    dfig.add_argument("--check", action="store_true", help="only say whether it is up to date")
    dfig.set_defaults(func=_cmd_docs_figures)
