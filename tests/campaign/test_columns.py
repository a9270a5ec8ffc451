"""The adapter's rules for a stage that raised, with the library's real exceptions."""

from __future__ import annotations

from usvlog.campaign import columns as C
from usvlog.campaign.table import to_frame
from usvlog.errors import InputError, UnusableResultError


def test_a_bad_input_fails_the_run_with_the_message():
    c = C.failure_columns("import", InputError("run.csv line 812: latitude 93.1 out of range"))
    assert c == {"status": "failed", "failed_stage": "import",
                 "reason": "import: run.csv line 812: latitude 93.1 out of range"}


def test_an_identification_that_refuses_its_result_is_an_unusable_run_not_a_failed_one():
    c = C.failure_columns("identify", UnusableResultError("yaw barely excited: Iz, d33 not determined"))
    assert c["status"] == "ok" and c["verdict"] == "unusable" and "failed_stage" not in c
    assert c["reason"] == "identify: unusable: yaw barely excited: Iz, d33 not determined"


def test_an_unexpected_exception_is_named_an_internal_error():
    c = C.failure_columns("estimate", ZeroDivisionError("float division by zero"))
    assert c["reason"] == "estimate: internal error (ZeroDivisionError): float division by zero"


def test_every_schema_column_is_in_the_table_even_with_only_failures():
    row = C.empty_row() | C.failure_columns("import", InputError("x.bin: empty file"))
    t = to_frame([row])
    assert list(t.columns) == list(C.SCHEMA) and t.loc[0, "status"] == "failed"
    assert str(t["start_utc"].dtype) == "datetime64[ns, UTC]" and str(t["d11"].dtype) == "float64"
