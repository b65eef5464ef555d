"""The one ``--option KEY=VALUE`` parser (host/options.py) behind tcomp fit, select and compare."""
import os

import pytest

from host.cli import main
from host.errors import UserError
from host.options import number, parse_options

RUN = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "data", "demo", "v8000_r210_490")


def test_typed_options_convert_and_refuse_with_the_reason():
    table = {"n": number(int, 1), "x": number(float), "word": str}
    assert parse_options(["n=3", " x = 0.5 ", "word=run_start"], table) == {"n": 3, "x": 0.5, "word": "run_start"}
    for item, reason in (("n=0", "must be >= 1"), ("n=2.5", "not a valid int"), ("x=nan", "must be a finite number"),
                         ("y=1", "KEY one of n, word, x"), ("n", "expected KEY=VALUE"), ("=3", "expected KEY=VALUE")):
        with pytest.raises(UserError, match=reason):
            parse_options([item], table)


def test_untyped_options_read_json_or_keep_the_word():
    assert parse_options(["seed=3", "alpha=0.01", "disturbance=offset", "flag=true"]) == {
        "seed": 3, "alpha": 0.01, "disturbance": "offset", "flag": True}


@pytest.mark.parametrize("argv", [
    ["fit", "--model", "mlr", RUN, "--out", "{tmp}/m.json"],
    ["fit", "--model", "screw", RUN, "--out", "{tmp}/m.json"],
    ["select", "--method", "maxtree", RUN, "--json", "{tmp}/s.json"],
])
def test_the_verbs_share_one_message_for_an_item_without_equals(capsys, tmp_path, argv):
    assert main([a.format(tmp=tmp_path) for a in argv] + ["--option", "seed"]) == 2
    assert "--option 'seed': expected KEY=VALUE" in capsys.readouterr().err
