"""The functions behind the commands, called without the command line: they check before any work.

Each command only parses its options and calls one of these; the checks below run before a device,
a model or a file is opened, so they are quick.
"""

from __future__ import annotations

import pytest

from facecapges.errors import UserError


def test_live_refuses_contradictory_options_before_opening_anything(tmp_path):
    from facecapges.runtime.live import run_live
    from facecapges.runtime.options import LiveOptions

    cases = [
        (LiveOptions(loop=True), "--loop needs --video"),
        (LiveOptions(realtime=True), "--realtime paces a --video file"),
        (LiveOptions(vrma=True, vmc="127.0.0.1:39539"), "--vrma records into --record DIR"),
        (LiveOptions(vmc_avatar=tmp_path / "a.vrm", web="127.0.0.1:0"), "--vmc-avatar needs --vmc"),
        (LiveOptions(web="127.0.0.1:0", max_seconds=0), "--max-seconds must be positive"),
        (LiveOptions(web="127.0.0.1:0", face_json="csv"), "--face-json csv: choose beat or full"),
        (LiveOptions(web="127.0.0.1:0", vmc_blend="arkit"), "--vmc-blend arkit"),
    ]
    for options, words in cases:
        with pytest.raises(UserError, match=words.replace(".", r"\.")):
            run_live(options)
    assert LiveOptions().camera is None  # run_live decides camera 0 on its own copy


def test_run_checks_the_video_size_and_the_inputs_first(tmp_path):
    from facecapges.runtime.options import RunOptions
    from facecapges.runtime.run import run_offline

    with pytest.raises(UserError, match="--video-size must look like 640x480"):
        run_offline(RunOptions(tmp_path / "missing.mp4", tmp_path / "out", video_size="big"))
    with pytest.raises(UserError, match=r"missing\.mp4"):
        run_offline(RunOptions(tmp_path / "missing.mp4", tmp_path / "out"))


def test_generate_and_render_refuse_to_overwrite(tmp_path):
    from facecapges.avatar.render.motion_file import RenderOptions, parse_render_size, render_motion_file
    from facecapges.runtime.generate import GenerateOptions, generate_recording

    out = tmp_path / "m.bvh"
    out.write_text("mine")
    with pytest.raises(UserError, match="--force"):
        generate_recording(GenerateOptions(tmp_path / "a.wav", out))
    mp4 = tmp_path / "v.mp4"
    mp4.write_bytes(b"mine")
    with pytest.raises(UserError, match="--force"):
        render_motion_file(RenderOptions(out, mp4))
    assert out.read_text() == "mine" and mp4.read_bytes() == b"mine"
    assert parse_render_size("320X240") == (320, 240)
    for bad in ("320", "8x8", "axb"):
        with pytest.raises(UserError, match="--size"):
            parse_render_size(bad)


def test_serve_config_names_the_option_at_fault():
    from facecapges.serving.config import ServeConfig

    ServeConfig().check()
    for kw, words in [({"port": 70000}, "--port 70000"), ({"tick_ms": -1}, "--tick-ms"),
                      ({"threads": 0}, "--threads"), ({"max_per_address": 0}, "--max-per-address")]:
        with pytest.raises(UserError, match=words):
            ServeConfig(**kw).check()


def test_the_command_line_reads_its_defaults_from_these_classes():
    """Every option of these commands that has a field of the same name defaults to that field's default."""
    import dataclasses

    import typer.main

    from facecapges.avatar.render.motion_file import RenderOptions
    from facecapges.commands.cli import app
    from facecapges.evaluation.options import AblateOptions, EvalOptions, FgdTrainOptions
    from facecapges.runtime.generate import GenerateOptions
    from facecapges.runtime.options import LiveOptions, RunOptions
    from facecapges.serving.config import ServeConfig
    from facecapges.study.options import StudyAnalyzeOptions, StudyCreateOptions, StudyServeOptions
    from facecapges.training.launch import TrainOptions

    group = typer.main.get_command(app)
    commands = dict(group.commands)
    commands.update({f"study {n}": c for n, c in group.commands["study"].commands.items()})
    pairs = [("live", LiveOptions), ("run", RunOptions), ("generate", GenerateOptions), ("render", RenderOptions),
             ("train", TrainOptions), ("serve", ServeConfig), ("eval", EvalOptions), ("ablate", AblateOptions),
             ("fgd-train", FgdTrainOptions), ("study create", StudyCreateOptions),
             ("study serve", StudyServeOptions), ("study analyze", StudyAnalyzeOptions)]
    for name, cls in pairs:
        params = {p.name: p.default for p in commands[name].params}
        fields = {f.name: f.default for f in dataclasses.fields(cls) if f.default is not dataclasses.MISSING}
        shared = set(params) & set(fields)
        assert len(shared) >= min(3, len(fields)), (name, shared)
        for field in shared:
            assert params[field] == fields[field], (name, field)


def test_the_library_takes_the_same_defaults_as_the_command_line():
    """The functions behind eval, ablate, fgd-train and study default to the option classes' values
    (eval and ablate take the options object itself, as run and live do)."""
    import dataclasses
    import inspect

    from facecapges.evaluation.ablate import VARIANTS, run_ablation
    from facecapges.evaluation.fgd import FGDConfig
    from facecapges.evaluation.options import OFFSETS, AblateOptions, EvalOptions, FgdTrainOptions, parse_offsets
    from facecapges.evaluation.regions import REGIONS
    from facecapges.evaluation.run import run_eval
    from facecapges.study.build import create_study
    from facecapges.study.options import StudyCreateOptions, StudyServeOptions
    from facecapges.study.server import make_server, serve_study

    def defaults(fn):
        return {k: v.default for k, v in inspect.signature(fn).parameters.items()}

    renamed = {"participants": "n_participants"}
    for fn, cls in [(create_study, StudyCreateOptions), (serve_study, StudyServeOptions),
                    (make_server, StudyServeOptions)]:
        got = defaults(fn)
        shared = [f for f in dataclasses.fields(cls) if renamed.get(f.name, f.name) in got]
        assert len(shared) >= 3, (fn.__name__, shared)
        for f in shared:
            assert got[renamed.get(f.name, f.name)] == f.default, (fn.__name__, f.name)
    for fn, cls in [(run_eval, EvalOptions), (run_ablation, AblateOptions)]:
        assert next(iter(inspect.signature(fn).parameters.values())).annotation in (cls, cls.__name__), fn.__name__
    assert parse_offsets(OFFSETS) == [float(s) for s in range(2, 61, 2)]
    assert tuple(AblateOptions.variants.split(",")) == VARIANTS
    assert tuple(FgdTrainOptions.regions.split(",")) == REGIONS
    fgd = FGDConfig()
    assert (FgdTrainOptions.epochs, FgdTrainOptions.batch_size, FgdTrainOptions.momentum, FgdTrainOptions.seed) == (
        fgd.epochs, fgd.batch_size, fgd.momentum, fgd.seed)
    assert AblateOptions.fgd_epochs == fgd.epochs
