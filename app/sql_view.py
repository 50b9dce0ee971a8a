"""How ``touch2robot sql`` shows what it finds: query results as a table, or one field per
line (like psql's ``\\x``) when a row is wider than the terminal; numbers rounded to
``SIGNIFICANT_DIGITS`` (``--csv`` keeps full precision), NULL written as NULL; the table
listing and a table's columns with their descriptions."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text
from typer.core import TyperCommand

if TYPE_CHECKING:  # pyarrow and duckdb are imported by the command itself, not by every command's start
    import pyarrow as pa

    from touch2robot.catalog import TableDescription

SIGNIFICANT_DIGITS = 6


class SqlCommand(TyperCommand):
    """The ``sql`` command, whose help lists every table of ``schemas.tables`` (imported only
    when the help is shown: pyarrow would slow every command's start)."""

    def format_help(self, ctx, formatter) -> None:  # types as TyperCommand.format_help (typer vendors click)
        from schemas.tables import SCHEMAS

        listing = f"Tables: {', '.join(SCHEMAS)} (`--tables` says what each holds)."
        if listing not in (self.help or ""):
            self.help = f"{self.help}\n\n{listing}"
        super().format_help(ctx, formatter)


def cell(value: Any) -> str:
    """A value as the table shows it: floats to ``SIGNIFICANT_DIGITS``, NULL as NULL, lists
    and structs element by element."""
    if value is None:
        return "NULL"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.{SIGNIFICANT_DIGITS}g}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(cell(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {cell(v)}" for k, v in value.items()) + "}"
    return str(value)


def _styled(value: Any) -> Text:
    return Text(cell(value), style="dim" if value is None else "")


def _rows(result: pa.Table, limit: int) -> list[tuple[Any, ...]]:
    # by position: a result may repeat a column name (SELECT 1 AS a, 2 AS a)
    shown = result.slice(0, limit)
    return list(zip(*(column.to_pylist() for column in shown.columns), strict=True))


def _horizontal(names: list[str], rows: list[tuple[Any, ...]]) -> Table:
    table = Table(*names)
    for row in rows:
        table.add_row(*(_styled(v) for v in row))
    return table


def _print_vertical(console: Console, names: list[str], rows: list[tuple[Any, ...]]) -> None:
    for number, row in enumerate(rows, 1):
        title = f"-[ RECORD {number} ]"
        console.print(title + "-" * max(0, min(console.width, 60) - len(title)), markup=False, highlight=False)
        record = Table.grid(padding=(0, 1))
        record.add_column(style="bold", no_wrap=True)
        record.add_column(overflow="fold")
        for name, value in zip(names, row, strict=True):
            record.add_row(Text(name), _styled(value))
        console.print(record)


def print_result(console: Console, result: pa.Table, limit: int, vertical: bool = False) -> None:
    """Up to ``limit`` rows of ``result``: as a table if its rows fit the terminal's width,
    else (or when ``vertical``) one field per line."""
    names = result.column_names
    rows = _rows(result, limit)
    table = _horizontal(names, rows)
    unbounded = console.options.update_width(sys.maxsize)  # measured as wide as its rows want
    if vertical or Measurement.get(console, unbounded, table).maximum > console.width:
        _print_vertical(console, names, rows)
    else:
        console.print(table)
    if result.num_rows > limit:
        console.print(f"... {result.num_rows - limit} more rows (use --csv or --limit)")
    elif not rows:
        console.print("(0 rows)")


def write_csv(result: pa.Table) -> None:
    """``result`` as CSV on stdout, at full precision; NULL is an empty field."""
    result.to_pandas().to_csv(sys.stdout, index=False)


def print_tables(console: Console, listing: pa.Table) -> None:
    """The table listing of ``touch2robot.catalog.tables``."""
    table = Table("table", "rows", "description")
    table.columns[1].justify = "right"
    for name, rows, description in _rows(listing, listing.num_rows):
        table.add_row(name, f"{rows:,}", description or "")
    console.print(table)


def print_description(console: Console, description: TableDescription) -> None:
    """A ``touch2robot.catalog.TableDescription``: the table's summary, partition keys, columns."""
    console.print(f"[bold]{description.name}[/bold]: {description.summary or ''}", highlight=False)
    if description.partition_keys:
        console.print(
            f"partitioned by {', '.join(description.partition_keys)} (folders lake/{description.name}/<key>=<value>/)",
            highlight=False,
        )
    table = Table("column", "type", "description")
    for column, sql_type, text, is_partition_key in _rows(description.columns, description.columns.num_rows):
        note = " (partition key)" if is_partition_key else ""
        table.add_row(column, sql_type, f"{text or ''}{note}")
    console.print(table)
