"""Table 1 and Table 2 from evaluation records (vgpl.eval.tables)."""

from __future__ import annotations

import pytest
import torch

from vgpl.eval.paired import paired_bootstrap, sign_test_p
from vgpl.eval.tables import (
    MIDPOINT_ROW,
    PER_VIDEO,
    csv_text,
    paired_by_horizon,
    paired_rows,
    paired_steps,
    paired_tables,
    param_rows,
    read_params_csv,
    report_markdown,
    table1_rows,
)
from vgpl.metrics import midpoint_error_pct


def _record(env: str, ablation: str, mae: float, midpoint: float | None = None) -> dict:
    record = {"env": env, "method": "vgpl", "ablation": ablation, "param_mae_pct": mae, "param_mae_pct_std": 1.0}
    if midpoint is not None:
        record |= {"midpoint_param_mae_pct": midpoint, "midpoint_param_mae_pct_std": 2.0}
    return record


def test_midpoint_error_is_the_distance_to_the_middle_of_the_range_in_percent():
    low, high = torch.tensor([-15.0, 0.25]), torch.tensor([-5.0, 1.25])
    truth = torch.tensor([[-15.0, 0.75], [-7.5, 1.0]])
    torch.testing.assert_close(midpoint_error_pct(truth, low, high), torch.tensor([[50.0, 0.0], [25.0, 25.0]]))


def test_table1_opens_with_the_constant_guess_of_each_env():
    records = [_record("rigid_fall", "full", 9.9, midpoint=25.6), _record("rigid_fall", "no_rigidness", 12.0, midpoint=25.6),
               _record("mass_rope", "full", 3.0, midpoint=24.0)]
    header, rows = table1_rows(records)
    assert header == ["method", "mass_rope", "rigid_fall"]
    assert rows[0] == [MIDPOINT_ROW, "24.0% (2.0)", "25.6% (2.0)"]
    assert rows[-1] == ["VGPL", "3.0% (1.0)", "9.9% (1.0)"]
    assert f"| {MIDPOINT_ROW} | 24.0% (2.0) | 25.6% (2.0) |" in report_markdown(records)


def test_records_without_the_midpoint_give_the_old_table():
    records = [_record("rigid_fall", "full", 9.9), _record("mass_rope", "full", 3.0, midpoint=24.0)]
    rows = table1_rows(records)[1]
    assert rows[0] == [MIDPOINT_ROW, "24.0% (2.0)", ""]  # an env evaluated before the key existed: an empty cell
    assert MIDPOINT_ROW not in report_markdown(records[:1])


def test_params_csv_has_one_row_per_video_with_true_and_inferred_values():
    header, rows = param_rows(["gravity"], torch.tensor([[-10.0], [-5.5]]), torch.tensor([[-9.25], [-6.0]]), torch.tensor([7, 3]))
    assert csv_text(header, rows) == "rollout_id,true_gravity,inferred_gravity\r\n7,-10,-9.25\r\n3,-5.5,-6\r\n"
    assert param_rows(["a", "b"], torch.zeros(1, 2), torch.ones(1, 2))[0] == ["rollout_id", "true_a", "inferred_a", "true_b", "inferred_b"]


def test_params_csv_carries_extra_per_video_columns_after_the_parameters():
    header, rows = param_rows(["stiffness"], torch.tensor([[0.3], [0.8]]), torch.tensor([[0.35], [0.7]]), None,
                              {"future_mse_x1e4@20": torch.tensor([12.5, 1.0e4])})
    assert csv_text(header, rows) == "rollout_id,true_stiffness,inferred_stiffness,future_mse_x1e4@20\r\n0,0.3,0.35,12.5\r\n1,0.8,0.7,10000\r\n"


def test_params_csv_reads_back_what_param_rows_wrote_and_selects_rows_by_rollout_id(tmp_path):
    path = tmp_path / "params.csv"
    path.write_text(csv_text(*param_rows(["a", "b"], torch.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]),
                                         torch.tensor([[1.5, 2.5], [3.5, 4.5], [5.5, 6.5]]), torch.tensor([907, 903, 905]),
                                         {"future_mse_x1e4@20": torch.tensor([7.0, 8.0, 9.0])})))
    table = read_params_csv(path, ["b", "a"], ("future_mse_x1e4@20",))
    assert table.rollout_ids == [907, 903, 905]
    assert table.truth.tolist() == [[2.0, 1.0], [4.0, 3.0], [6.0, 5.0]]  # in the order of the names asked for
    assert table.inferred.tolist() == [[2.5, 1.5], [4.5, 3.5], [6.5, 5.5]]
    chosen = table.select([905, 907])
    assert chosen.rollout_ids == [905, 907] and chosen.inferred[:, 1].tolist() == [5.5, 1.5]
    assert chosen.columns["future_mse_x1e4@20"].tolist() == [9.0, 7.0]
    with pytest.raises(ValueError, match=r"params\.csv: no row for rollouts \[904\]"):
        table.select([903, 904])


def test_params_csv_of_another_env_or_a_missing_file_is_one_error_naming_the_file(tmp_path):
    path = tmp_path / "params.csv"
    path.write_text(csv_text(*param_rows(["gravity"], torch.zeros(2, 1), torch.ones(2, 1))))
    with pytest.raises(ValueError, match=r"params\.csv: columns \['true_stiffness', 'inferred_stiffness'\] missing"):
        read_params_csv(path, ["stiffness"])
    with pytest.raises(ValueError, match=r"params\.csv: columns \['future_mse_x1e4@20'\] missing"):
        read_params_csv(path, ["gravity"], ("future_mse_x1e4@20",))
    with pytest.raises(ValueError, match=r"nothing/params\.csv: no such file"):
        read_params_csv(tmp_path / "nothing/params.csv", ["gravity"])
    path.write_text("rollout_id,true_gravity,inferred_gravity\n")
    with pytest.raises(ValueError, match=r"params\.csv: no rows"):
        read_params_csv(path, ["gravity"])


def _with_videos(env: str, ablation: str, errors: list[float], first_id: int = 900) -> dict:
    return _record(env, ablation, 10.0) | {PER_VIDEO.format(20): {str(first_id + i): e for i, e in enumerate(errors)}}


def test_bootstrap_of_a_constant_gap_is_that_gap_and_of_noise_straddles_zero():
    reference = torch.linspace(10, 100, 50)
    shifted = paired_bootstrap(reference, reference + 3.0)
    assert shifted["mean_diff"] == pytest.approx(3.0) and shifted["low"] == pytest.approx(3.0) and shifted["high"] == pytest.approx(3.0)
    assert shifted["reference_lower_share"] == 1.0 and shifted["videos"] == 50
    noise = torch.tensor([1.0, -1.0] * 25) * torch.linspace(1, 5, 50)
    straddle = paired_bootstrap(reference, reference + noise)
    assert straddle["low"] < 0 < straddle["high"] and straddle["reference_lower_share"] == 0.5


def test_sign_test_is_the_exact_binomial_tail_with_ties_dropped():
    assert sign_test_p(torch.ones(10)) == pytest.approx(2 / 2**10)
    # 15 of 20 one way: 2 * (C(20,0) + ... + C(20,5)) / 2^20 = 2 * 21,700 / 1,048,576
    assert sign_test_p(torch.tensor([1.0] * 15 + [-2.0] * 5)) == pytest.approx(2 * 21700 / 2**20)
    assert sign_test_p(torch.tensor([1.0] * 15 + [-2.0] * 5 + [0.0] * 7)) == pytest.approx(2 * 21700 / 2**20)  # ties dropped
    assert sign_test_p(torch.tensor([1.0, -1.0] * 5)) == 1.0 and sign_test_p(torch.zeros(4)) == 1.0
    assert sign_test_p(torch.tensor([1.0] * 10 + [float("nan")] * 3)) == pytest.approx(2 / 2**10)  # NaN: no sign, dropped
    # a heavy tail moves the mean, not the sign test: 69 of 100 lower by 1, 31 higher by 10
    diff = torch.tensor([1.0] * 69 + [-10.0] * 31)
    assert diff.mean() < 0 and sign_test_p(diff) < 2e-4 and paired_bootstrap(-diff, torch.zeros(100))["sign_p"] == sign_test_p(diff)


def test_paired_table_says_whether_vgpl_is_lower_on_the_same_videos():
    full = _with_videos("mass_rope", "full", [10.0, 20.0, 30.0, 40.0])
    records = [full,
               _with_videos("mass_rope", "no_refinement", [15.0, 26.0, 34.0, 46.0]),  # higher on every video
               _with_videos("mass_rope", "no_params", [12.0, 14.0, 33.0, 38.0]),  # mixed
               _with_videos("mass_rope", "no_rigidness", [1.0, 2.0, 3.0, 4.0, 5.0], first_id=902)]  # only 902, 903 shared
    assert paired_steps(records) == [20]
    header, rows = paired_rows(records, 20)
    by = {r[1]: dict(zip(header, r)) for r in rows}
    assert by["VGPL w/o refinement"]["VGPL is"] == "lower" and by["VGPL w/o refinement"]["videos where VGPL is lower (sign test p)"] == "100% (p 0.12)"  # 2 / 2^4
    assert by["VGPL w/o refinement"]["mean difference (ablation - VGPL) [95% bootstrap]"].startswith("+5.250 [")
    assert by["VGPL w/o parameter estimation"]["VGPL is"] == "not distinguishable"
    assert by["VGPL w/o rigidness (Q = 0)"]["videos"] == "2" and by["VGPL w/o rigidness (Q = 0)"]["VGPL T+20"] == "35.000"  # videos 902, 903
    assert by["VGPL w/o rigidness (Q = 0)"]["VGPL is"] == "higher"
    # a mean swung by one video's tail, while VGPL is lower on 19 of 20: the sign test says so
    tail = [_with_videos("rigid_fall", "full", [10.0] * 19 + [400.0]), _with_videos("rigid_fall", "no_params", [12.0] * 19 + [200.0])]
    header, rows = paired_rows(tail, 20)
    assert dict(zip(header, rows[0]))["VGPL is"] == "not distinguishable in the mean; lower on most videos"
    assert dict(zip(header, rows[0]))["videos where VGPL is lower (sign test p)"] == "95% (p < 1e-4)"  # 2 * 21 / 2^20 = 4.0e-5
    report = report_markdown(records)  # one table, ablation by horizon: the verdict, the mean difference, the share of videos
    assert report.count("## Is VGPL lower") == 1
    assert "| mass_rope | VGPL w/o refinement | 4 | lower: +5.250 [" in report and "]; 100% (p 0.12) |" in report
    assert "| mass_rope | VGPL w/o rigidness (Q = 0) | 2 | higher: " in report
    assert "Is VGPL lower" not in report_markdown([_record("mass_rope", "full", 3.0)])  # older records: no section


def test_the_paired_table_folds_the_horizons_into_columns():
    """Each (env, ablation) is one row and each T+k one column, whatever horizons the records carry."""
    records = [_with_videos("rigid_fall", "full", [10.0, 20.0, 30.0]), _with_videos("rigid_fall", "no_params", [11.0, 21.0, 31.0])]
    for r, extra in zip(records, ([1.0, 2.0, 3.0], [0.5, 1.0, 1.5])):  # at T+1 the ablation is lower on every video
        r[PER_VIDEO.format(1)] = {str(i): v for i, v in zip(range(900, 903), extra)}
    header, rows = paired_by_horizon(paired_tables(records))
    assert header == ["env", "ablation", "videos", "T+1", "T+20"]
    assert len(rows) == 1 and rows[0][:3] == ["rigid_fall", "VGPL w/o parameter estimation", "3"]
    assert rows[0][3].startswith("higher: -1.000 [") and rows[0][3].endswith("; 0% (p 0.25)")
    assert rows[0][4].startswith("lower: +1.000 [") and rows[0][4].endswith("; 100% (p 0.25)")


def test_every_section_lists_the_envs_in_the_papers_order_whatever_order_the_sweep_wrote_them():
    """A multirun over env=rigid_fall,fluid_cube,mass_rope writes its records in job order; the
    report's refinement, rigidness and paired sections follow Table 1's columns (MassRope,
    RigidFall, FluidCube), as the paper does."""
    records = []
    for env in ("rigid_fall", "fluid_cube", "mass_rope"):
        full = _with_videos(env, "full", [10.0, 20.0]) | {"refine_mse_x1e4_before": 2.0, "refine_mse_x1e4_after": 1.0,
                                                         f"rigidness_prob@10/{env}_object": 0.9}
        records += [full, _with_videos(env, "no_params", [15.0, 26.0])]
    report = report_markdown(records)
    assert report.index("| mass_rope | 2.000") < report.index("| rigid_fall | 2.000") < report.index("| fluid_cube | 2.000")
    assert "| rigid_fall | 2.000 (14.1 mm) | 1.000 (10.0 mm) |" in report  # RMS per coordinate: 10 sqrt(MSE x 1e4)
    assert report.index("| mass_rope | mass_rope_object") < report.index("| rigid_fall | rigid_fall_object") < report.index("| fluid_cube | fluid_cube_object")
    paired = report[report.index("## Is VGPL lower"):]
    assert paired.index("| mass_rope |") < paired.index("| rigid_fall |") < paired.index("| fluid_cube |")


def test_densephysnet_rows_say_which_flow_it_learned():
    """The baseline on the simulator's flow is labelled privileged, and never pooled with the one on
    estimated flow (a record without the key was trained on the simulator's)."""
    from vgpl.eval.tables import table1_rows

    base = {"env": "rigid_fall", "method": "densephysnet", "ablation": "full", "param_mae_pct": 4.0, "param_mae_pct_std": 1.0}
    header, rows = table1_rows([base, {**base, "flow": "farneback", "param_mae_pct": 20.0}])
    names = {row[0]: row[1] for row in rows}
    assert names == {"DensePhysNet (simulator flow, privileged)": "4.0% (1.0)", "DensePhysNet": "20.0% (1.0)"}
