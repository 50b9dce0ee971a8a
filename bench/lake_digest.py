"""Content digests of every lake table of a data folder, order-independent, so that two data folders
(e.g. a smoke run before and after a refactor) can be compared table by table.

    uv run python bench/lake_digest.py DATA_A [DATA_B]

Columns that hold run-specific values (absolute paths, wall-clock times, MLflow run ids) are left out."""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import duckdb

VOLATILE = {"path", "ingested_at", "mlflow_run", "ratings_file"}


def digests(data: Path) -> dict[str, tuple[int, str]]:
    con = duckdb.connect()
    out = {}
    for table in sorted(p.name for p in (data / "lake").iterdir() if p.is_dir()):
        files = sorted((data / "lake" / table).rglob("*.parquet"))
        rel = con.sql(
            "SELECT * FROM read_parquet($files, hive_partitioning = true, union_by_name = true)",
            params={"files": [str(f) for f in files]},
        )
        cols = [c for c in rel.columns if c not in VOLATILE]
        names = ", ".join(f'"{c}"' for c in cols)
        rows = con.sql(
            f"SELECT md5(string_agg(h, ',' ORDER BY h)) AS d, count(*) AS n "
            f"FROM (SELECT md5(CAST(ROW({names}) AS VARCHAR)) AS h FROM rel)"
        ).fetchall()[0]
        ids = hashlib.md5("\n".join(str(f.relative_to(data / "lake")) for f in files).encode()).hexdigest()
        out[table] = (rows[1], f"{rows[0]}/{ids[:8]}")
    return out


def main() -> None:
    folders = [Path(a) for a in sys.argv[1:]]
    results = [digests(f) for f in folders]
    tables = sorted(set().union(*results))
    same = True
    for t in tables:
        cells = [r.get(t) for r in results]
        flag = "" if len(set(cells)) == 1 else "  DIFFERS"
        same &= not flag
        print(f"{t:22s} " + "  ".join(f"{c[0]:>8} {c[1]}" if c else "missing" for c in cells) + flag)
    if len(folders) > 1:
        print("identical" if same else "tables differ")
        sys.exit(0 if same else 1)


if __name__ == "__main__":
    main()
