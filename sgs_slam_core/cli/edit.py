"""``sgs-slam edit``: remove, keep, move/rotate or recolour objects of a saved map by class."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from sgs_slam_core.cli.args import FloatRange, IntRange
from sgs_slam_core.editing import EditError, EditKind, EditRequest, Selection, apply_edit
from sgs_slam_core.errors import MapFileError
from sgs_slam_core.mapio import MAP_SUFFIXES, read_any_map, write_any_map

__all__ = ["add_parser", "parse_label", "run"]

_FINITE = FloatRange()
_UNIT = FloatRange(0.0, 1.0)
_INSTANCE = IntRange(0)
_LINK = FloatRange(0.0, 100.0, lo_open=True)


def parse_label(text: str) -> int | str:
    """A class given on the command line: an id (``5``) or a name (``chair``)."""
    return int(text) if text.lstrip("-").isdigit() else text


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the sub-command."""
    p = sub.add_parser(
        "edit",
        help="remove, keep, move or recolour objects of a map by class",
        description="Edit a map (.sgsmap or .ply) by class; writes a new map, the input is untouched. "
        "Edited classes are locked in a .sgsmap output: resumed mapping ignores their pixels, so a "
        "removed object does not grow back (use --no-lock to allow it).",
    )
    p.add_argument("map", type=Path, help="input map (.sgsmap or .ply)")
    op = p.add_mutually_exclusive_group(required=True)
    op.add_argument("--remove-label", nargs="+", type=parse_label, metavar="L", help="delete these classes")
    op.add_argument("--keep-label", nargs="+", type=parse_label, metavar="L", help="keep only these classes")
    op.add_argument("--move-label", nargs="+", type=parse_label, metavar="L", help="move/rotate these classes")
    op.add_argument("--recolor-label", nargs="+", type=parse_label, metavar="L", help="paint these classes")
    p.add_argument(
        "--translate",
        nargs=3,
        type=_FINITE,
        default=(0.0, 0.0, 0.0),
        metavar=("X", "Y", "Z"),
        help="translation in metres, map frame (with --move-label)",
    )
    p.add_argument(
        "--rotate-deg",
        nargs=3,
        type=_FINITE,
        default=(0.0, 0.0, 0.0),
        metavar=("RX", "RY", "RZ"),
        help="rotation about the map's x, y, z axes in degrees, applied before the translation",
    )
    p.add_argument(
        "--pivot",
        nargs=3,
        type=_FINITE,
        metavar=("X", "Y", "Z"),
        help="rotation centre in metres (default: the selection's centroid)",
    )
    p.add_argument("--rgb", nargs=3, type=_UNIT, metavar=("R", "G", "B"), help="colour in [0, 1] (--recolor-label)")
    p.add_argument("--instance", type=_INSTANCE, help="only the K-th connected object of the classes (0 = largest)")
    p.add_argument(
        "--link",
        type=_LINK,
        default=0.05,
        help=f"distance in m joining Gaussians into one instance ({_LINK.bounds}; 0.05)",
    )
    p.add_argument(
        "--box",
        nargs=6,
        type=_FINITE,
        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
        help="only Gaussians inside this axis-aligned box (m)",
    )
    p.add_argument("--no-lock", action="store_true", help="do not lock the edited classes in the output map")
    p.add_argument("--out", type=Path, required=True, help="output map (.sgsmap or .ply)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.set_defaults(func=run)


def request_from_args(args: argparse.Namespace) -> EditRequest:
    """The edit the arguments describe."""
    box = None if args.box is None else (tuple(args.box[:3]), tuple(args.box[3:]))
    given = {
        EditKind.REMOVE: args.remove_label,
        EditKind.KEEP: args.keep_label,
        EditKind.MOVE: args.move_label,
        EditKind.RECOLOR: args.recolor_label,
    }
    kind, labels = next((k, v) for k, v in given.items() if v)  # argparse requires exactly one
    selection = Selection(tuple(labels), box, args.instance, args.link)
    if kind is not EditKind.MOVE and (any(args.translate) or any(args.rotate_deg) or args.pivot):
        raise EditError("--translate, --rotate-deg and --pivot go with --move-label")
    if kind is not EditKind.RECOLOR and args.rgb:
        raise EditError("--rgb goes with --recolor-label")
    pivot = tuple(args.pivot) if args.pivot else None
    rgb = tuple(args.rgb) if args.rgb else None
    return EditRequest(kind, selection, tuple(args.translate), tuple(args.rotate_deg), pivot, rgb)


def run(args: argparse.Namespace) -> int:
    """Load, edit, write, print what changed."""
    if args.out.suffix.lower() not in MAP_SUFFIXES:
        raise MapFileError(f"--out {args.out}: map files end in {' or '.join(MAP_SUFFIXES)}")
    if args.out.exists() and not args.overwrite:
        raise MapFileError(f"{args.out} exists (use --overwrite to replace it)")
    if args.out.resolve() == args.map.resolve():
        raise MapFileError("--out must differ from the input map (the input is never modified)")
    request = request_from_args(args)
    saved = read_any_map(args.map)
    edited, record = apply_edit(saved.gaussians, request, saved.label_table)
    locked = saved.locked_labels if args.no_lock else sorted({*saved.locked_labels, *record.labels})
    write_any_map(args.out, replace(saved, gaussians=edited, locked_labels=locked))
    names = ", ".join(f"{i} ({saved.label_table.name_of(i)})" for i in record.labels)
    verb = {
        EditKind.REMOVE: "removed",
        EditKind.KEEP: "dropped",
        EditKind.MOVE: "moved",
        EditKind.RECOLOR: "recoloured",
    }
    print(f"{verb[record.kind]} {record.count} Gaussians of {names}; {record.before} -> {record.after} in {args.out}")
    if record.transform is not None:
        t = record.transform[:3, 3]
        print(
            f"  about pivot {tuple(round(v, 4) for v in record.pivot)}; world transform translation "
            f"[{t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}] m"
        )
    return 0
