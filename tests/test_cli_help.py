"""Every command line's help reads in full: its ``python -m`` name, a whole description, examples
that use that name; every option says what it does and, when it has one, its default."""

import argparse

import pytest


class Captured(Exception):
    def __init__(self, parser):
        self.parser = parser


def parser_of(main, argv):
    """The ArgumentParser a CLI's main builds (caught at parse time)."""
    original = argparse.ArgumentParser.parse_args

    def capture(self, *a, **k):
        raise Captured(self)

    argparse.ArgumentParser.parse_args = capture
    try:
        main(argv)
    except Captured as c:
        return c.parser
    finally:
        argparse.ArgumentParser.parse_args = original
    raise AssertionError("no parser was built")


def undocumented(parser, prefix=""):
    bad = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                bad += undocumented(sub, f"{prefix}{name} ")
            continue
        name = prefix + (action.option_strings[-1] if action.option_strings else action.dest)
        text = (action.help or "").lower()
        if not text.strip():
            bad.append(f"{name}: no description")
        elif (action.option_strings and not action.required and action.default not in (None, False)
              and "default" not in text and str(action.default) not in text):
            bad.append(f"{name}: default {action.default!r} not stated")
    return bad


def _mains():
    from bench.conv import main as bench_conv_main
    from bench.coverage import main as bench_coverage_main
    from bench.load import main as bench_load_main
    from bench.octree_build import main as bench_build_main
    from bench.octree_label_changes import main as bench_labels_main
    from bench.octree_scaling import main as bench_scaling_main
    from bench.octree_versions import main as bench_versions_main
    from bench.onnx_decode import main as bench_onnx_main
    from bench.requests import main as bench_requests_main
    from bench.symmetry import main as bench_symmetry_main
    from bench.train_step import main as bench_step_main
    from export.__main__ import main as export_main
    from export.quantize import main as quantize_main
    from model.data.__main__ import main as data_main
    from model.data.contact_sheet import main as sheet_main
    from model.octree.__main__ import main as octree_main
    from model.train.__main__ import main as train_main
    from research.calibrate import main as calibrate_main
    from research.choose import main as choose_main
    from research.curves import main as curves_main
    from research.degrade import main as degrade_main
    from research.evaluate import main as evaluate_main
    from research.figures import main as figures_main
    from research.release import main as release_main
    from research.results_table import main as table_main
    from service.__main__ import main as service_main
    return {"model.data.contact_sheet": sheet_main, "bench.conv": bench_conv_main, "bench.coverage": bench_coverage_main,
            "bench.octree_build": bench_build_main, "bench.octree_label_changes": bench_labels_main,
            "bench.octree_versions": bench_versions_main, "bench.symmetry": bench_symmetry_main, "model.train": train_main,
            "research.evaluate": evaluate_main, "model.data": data_main,
            "model.octree": octree_main, "research.results_table": table_main, "research.figures": figures_main,
            "research.curves": curves_main, "research.choose": choose_main,
            "research.release": release_main, "research.calibrate": calibrate_main, "export": export_main,
            "export.quantize": quantize_main, "service": service_main, "bench.onnx_decode": bench_onnx_main,
            "bench.load": bench_load_main, "bench.octree_scaling": bench_scaling_main,
            "bench.train_step": bench_step_main, "research.degrade": degrade_main,
            "bench.requests": bench_requests_main}


@pytest.mark.parametrize("name", sorted(_mains()))
def test_every_option_has_a_description_and_states_its_default(name):
    assert undocumented(parser_of(_mains()[name], [])) == []


@pytest.mark.parametrize("name", sorted(_mains()))
def test_help_names_the_command_describes_it_whole_and_gives_examples(name):
    parser = parser_of(_mains()[name], [])
    assert parser.prog == f"python -m {name}"
    text = parser.description or ""
    assert len(text) > 30 and text.rstrip().endswith((".", ")")), text
    assert "``" not in text
    examples = (parser.epilog or "").splitlines()
    assert examples[0] == "examples:" and all(f"python -m {name}" in e for e in examples[1:] if "python" in e)
    assert any(f"python -m {name}" in e for e in examples[1:])
    assert "usage: python -m" in parser.format_help()
