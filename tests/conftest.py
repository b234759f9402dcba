from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
REAL = (ROOT / ".." / "shared" / "data" / "real").resolve()


def real_sequence(name: str) -> Path:
    """Folder of a real sequence in ../shared/data/real; skip the test when it is absent."""
    folder = REAL / name
    if not (folder / "frames").is_dir():
        pytest.skip(f"real data {folder} is not available (../shared/data/real beside the repo)")
    return folder


@pytest.fixture
def cli(tmp_path, monkeypatch, capsys):
    """Run the CLI in a temporary folder; returns (exit code, stdout, stderr)."""
    from irdetect.cli import main

    monkeypatch.chdir(tmp_path)

    def run(*argv):
        code = main([str(a) for a in argv])
        out = capsys.readouterr()
        return code, out.out, out.err

    return run
