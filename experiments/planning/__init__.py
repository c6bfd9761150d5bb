"""ns2exp.planning: the paper's planning experiments (SL, SS, LL, SSL, SLL; NN vs BL),
one module per job:

cases.py        the cases: scenarios, the experiments' limits, scenario_problem
runs.py         one trial planned, checked and flown; a case's summary; the workers (executor)
calibrated.py   the margin of a run: measured on held-out flights, calibrated on the
                planner's own flown plans
retraining.py   the planning model retrained on its own flown plans
store.py        the finished work of a run, kept so that a run cut short resumes
reports.py      the model check, tables and figures
experiment.py   planning_experiments: every case with NN and BL, written as plan.json,
                plan.md and figures
compare.py      python -m ns2exp.planning.compare: several checkpoints' margins side by side

The product side of planning lives elsewhere: problem files in ns2plan.problemfile,
the planning model trained on simulated flights in ns2host.sim.planmodel."""
from .calibrated import (CALIBRATION_PLANS, CALIBRATION_ROUNDS, CALIBRATION_SEEDS, calibrated_margin,
                         calibration_wave, measured_margin)
from .cases import FA_MARGIN_G, HEIGHT, LIMITS_2D, LIMITS_3D, NEAR_FIELD_M, SCENARIOS, SPACING, scenario_problem
from .experiment import planning_experiments
from .reports import (CHECK_GAPS, PROFILE_COLUMNS, downwash_check, downwash_table, example_figure, profile_table,
                      summary_figure, table)
from .retraining import PLAN_DATA_ROUNDS, PLAN_DATA_SEEDS, plan_trained_checkpoint, training_data_files
from .runs import fly_plans, over_limit, run_trial, trial_summary, unforeseen
from .store import RESUME_DIR, TrialStore, runs_folder

__all__ = ["CALIBRATION_PLANS", "CALIBRATION_ROUNDS", "CALIBRATION_SEEDS", "CHECK_GAPS", "FA_MARGIN_G", "HEIGHT",
           "LIMITS_2D", "LIMITS_3D", "NEAR_FIELD_M", "PLAN_DATA_ROUNDS", "PLAN_DATA_SEEDS", "PROFILE_COLUMNS",
           "RESUME_DIR", "SCENARIOS", "SPACING", "TrialStore", "calibrated_margin", "calibration_wave",
           "downwash_check", "downwash_table", "example_figure", "fly_plans", "measured_margin", "over_limit",
           "plan_trained_checkpoint", "planning_experiments", "profile_table", "run_trial", "runs_folder",
           "scenario_problem", "summary_figure", "table", "training_data_files", "trial_summary", "unforeseen"]
