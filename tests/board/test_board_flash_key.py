"""`tcomp flash --key`: no copy of a board key is written by a dry run or left by a failed flash (issue 22).

hostsec24 made the key FILE appear only after a successful flash; what remained: a dry run staged the key
(``tables/key.bin``) in the folder it keeps for the printed command, a copy of the secret left in a
temporary folder. Here every byte written anywhere under the temporary folder is searched for the key."""
import os
import random
import tempfile

import pytest

from host.cli import main


@pytest.fixture
def table(tmp_path):
    from hil_tests.fixtures.samples import poly_slope_doc
    from models_export.export import export_model
    path = tmp_path / "t.bin"
    path.write_bytes(export_model(poly_slope_doc(random.Random(7), n_sensors=2)).table)
    return str(path)


@pytest.fixture
def scratch(tmp_path, monkeypatch):
    """Where tempfile puts the staging folders during the test (searched afterwards)."""
    d = tmp_path / "tmp"
    d.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(d))
    return d


def _key_copies(folder, key):
    """Files under ``folder`` holding the key, raw (key.bin) or as hex (a key file)."""
    found = []
    for root, _, names in os.walk(folder):
        for n in names:
            data = open(os.path.join(root, n), "rb").read()
            if key in data or key.hex().encode() in data.lower():
                found.append(os.path.relpath(os.path.join(root, n), folder))
    return found


def _existing_key(tmp_path):
    from host.board.linkauth import generate_key, write_key
    key = generate_key()
    write_key(str(tmp_path / "board.key"), key)
    return key, str(tmp_path / "board.key")


def test_dry_run_stages_no_copy_of_an_existing_key(tmp_path, table, scratch, capsys):
    key, path = _existing_key(tmp_path)
    assert main(["flash", "--port", "/dev/null", "--table", table, "--no-firmware", "--key", path, "--dry-run"]) == 0
    out, err = capsys.readouterr()
    kept = [d for d in os.listdir(scratch)]
    assert len(kept) == 1 and os.path.join(str(scratch), kept[0]) in err  # the command's files are kept ...
    assert os.path.isfile(scratch / kept[0] / "tables" / "table_a.bin")
    assert _key_copies(scratch, key) == [], "a dry run left the key in %s" % kept  # ... but never the key
    assert "key.bin" not in out and "does not provision it" in err
    assert key.hex() not in (out + err).lower()


def test_dry_run_with_a_missing_key_file_writes_nothing(tmp_path, table, scratch, capsys):
    assert main(["flash", "--port", "/dev/null", "--table", table, "--no-firmware", "--dry-run",
                 "--key", str(tmp_path / "new.key")]) == 2
    assert "a dry run creates no key" in capsys.readouterr().err
    assert not os.path.lexists(tmp_path / "new.key") and os.listdir(scratch) == []


@pytest.mark.parametrize("existing", [True, False])
def test_failed_flash_leaves_no_key_anywhere(tmp_path, table, scratch, capsys, existing):
    fake = tmp_path / "mpremote"
    fake.write_text('#!/bin/sh\ncase "$*" in *"fs cp"*) echo "copy failed" >&2; exit 1;; *) echo tcomp-probe;; esac\n')
    fake.chmod(0o755)
    if existing:
        key, path = _existing_key(tmp_path)
    else:
        key, path = None, str(tmp_path / "new.key")
    rc = main(["flash", "--port", "/dev/null", "--table", table, "--no-firmware", "--mpremote", str(fake),
               "--key", path])
    assert rc == 2 and "copy failed" in capsys.readouterr().err
    assert os.listdir(scratch) == []  # the staged key.bin went with its folder
    if existing:
        assert _key_copies(scratch, key) == []
    else:
        assert not os.path.lexists(path)
