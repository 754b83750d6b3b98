#!/usr/bin/env bash
# The accuracy experiments of the select/optimize/rank switches on the validation scenes (never caddeo2023):
# one JSON line per (configuration, method) from scripts/eval_accuracy.py.
#   scripts/accuracy_table.sh [ARTIFACTS] [SCENES] > results.jsonl
set -u
ART=${1:-artifacts}
SET=${2:-validation}
PY=${PYTHON:-python}
PAPER="select.delta_d_rule=paper select.normal_tol_deg=null optimize.normal_weight=0.0 rank.refine=false"
BEST_N="select.delta_d_rule=best_n select.normal_tol_deg=null optimize.normal_weight=0.0 rank.refine=false"
REFINE="select.delta_d_rule=best_n select.normal_tol_deg=null optimize.normal_weight=0.0 rank.refine=true"
NORMALS="select.delta_d_rule=best_n select.normal_tol_deg=20 optimize.normal_weight=0.01 rank.refine=true"
for config in PAPER BEST_N REFINE NORMALS; do
  for method in ours baseline; do
    $PY "$(dirname "$0")/eval_accuracy.py" --artifacts "$ART" --scenes "$SET" --method "$method" ${!config} \
      | sed "s/^{/{\"config\": \"$config\", /"
  done
done
