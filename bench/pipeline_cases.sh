#!/bin/sh
# Diagnose bench/pipeline_records.py's records with this tree's CLI: text summary, JSON and the CPU seconds of each
# run, into OUT; CASE.text and CASE.json are those without the elapsed time (the summary's "(N s)" line, the JSON's
# "seconds"): diff them between two OUT folders to check a refactor byte for byte.
# Run:  nice -n 10 sh bench/pipeline_cases.sh RECORDS OUT [CASE ...]   (from the repository root; default: all)
set -u
records=$1; out=$2; shift 2
mkdir -p "$out"
python=${PYTHON:-/work/main/.venv/bin/python}
cases=${*:-"clean coulomb two two_add cable_small encoder inflow brush heating reaction joint"}
for case in $cases; do
    case $case in
        two_add) args="$records/two.csv --add coulomb_friction" ;;
        joint) args="$records/joint_a.csv $records/joint_b.csv" ;;
        *) args="$records/$case.csv" ;;
    esac
    /usr/bin/time -f '%U %S' -o "$out/$case.time" env PYTHONPATH="$PWD" OPENBLAS_NUM_THREADS=1 "$python" -c \
        'import sys; from aeropend_core.cli import main; sys.exit(main())' diagnose $args --quiet \
        --json "$out/$case.raw.json" > "$out/$case.txt" 2> "$out/$case.err"
    echo $? > "$out/$case.rc"
    grep -v '"seconds":' "$out/$case.raw.json" > "$out/$case.json" 2>/dev/null
    grep -Ev '^\([0-9.]+ s\)$' "$out/$case.txt" > "$out/$case.text"
    echo "$case rc=$(cat "$out/$case.rc") cpu=$(awk '{print $1+$2}' "$out/$case.time") s"
done
