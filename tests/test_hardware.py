"""The CPU description benchmarks print, and the warning for bf16 on a CPU that emulates it."""

from vgpl.hardware import bf16_native, cpu_family_model, cpu_info, precision_warning

CASCADE_LAKE = frozenset({"avx2", "avx512f", "avx512_vnni"})
ZEN4 = CASCADE_LAKE | {"avx512_bf16"}
SAPPHIRE_RAPIDS = CASCADE_LAKE | {"amx_bf16", "amx_tile"}


def test_bf16_is_native_only_with_avx512_bf16_or_amx():
    assert bf16_native(CASCADE_LAKE) is False
    assert bf16_native(ZEN4) is True and bf16_native(SAPPHIRE_RAPIDS) is True
    assert bf16_native(frozenset()) is None  # unreadable flags: unknown, not "no"


def test_cpu_info_reads_model_and_flags(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: Test CPU @ 1GHz\nflags\t\t: fpu avx2 avx512f\n\nprocessor\t: 1\nflags\t\t: fpu\n")
    assert cpu_info(str(info)) == ("Test CPU @ 1GHz", frozenset({"fpu", "avx2", "avx512f"}))
    assert cpu_info(str(tmp_path / "missing"))[1] == frozenset()


def test_cpu_generation_reads_family_and_model_not_model_name(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\ncpu family\t: 26\nmodel\t\t: 2\nmodel name\t: AMD EPYC\n")
    assert cpu_family_model(str(info)) == "family 26 model 2"
    info.write_text("processor\t: 0\nmodel name\t: AMD EPYC\n")
    assert cpu_family_model(str(info)) is None
    assert cpu_family_model(str(tmp_path / "missing")) is None


def test_bf16_warning_only_where_a_cpu_would_emulate_it():
    warning = precision_warning("bf16-mixed", "auto", cuda=False, flags=CASCADE_LAKE)
    assert "trainer.precision=bf16-mixed" in warning and "32-true" in warning
    assert precision_warning("bf16-mixed", "cpu", cuda=True, flags=CASCADE_LAKE) is not None  # forced onto the CPU
    assert precision_warning("bf16-mixed", "auto", cuda=False, flags=ZEN4) is None
    assert precision_warning("bf16-mixed", "auto", cuda=True, flags=CASCADE_LAKE) is None  # trains on the GPU
    assert precision_warning("bf16-mixed", "gpu", cuda=True, flags=CASCADE_LAKE) is None
    assert precision_warning("32-true", "cpu", cuda=False, flags=CASCADE_LAKE) is None
    assert precision_warning("bf16-mixed", "cpu", cuda=False, flags=frozenset()) is None  # unknown CPU: no guess


def test_fast_precision_keeps_bf16_only_where_it_is_fast():
    from omegaconf import OmegaConf

    from vgpl.hardware import fast_precision

    assert fast_precision("bf16-mixed", cuda=False, flags=CASCADE_LAKE) == "32-true"
    assert fast_precision("bf16-mixed", cuda=False, flags=ZEN4) == "bf16-mixed"
    assert fast_precision("bf16-mixed", cuda=True, flags=CASCADE_LAKE) == "bf16-mixed"
    assert fast_precision("bf16-mixed", cuda=False, flags=frozenset()) == "bf16-mixed"  # unknown CPU: as asked
    assert fast_precision("16-mixed", cuda=False, flags=CASCADE_LAKE) == "16-mixed"
    # the resolver a config can ask for, registered on import vgpl
    resolved = OmegaConf.create({"precision": "${fast_precision:bf16-mixed}"}).precision
    assert resolved == fast_precision("bf16-mixed")
