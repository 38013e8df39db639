"""Property-based run against the service's own OpenAPI (issue 17, item 5): every operation gets valid
and invalid requests generated from its schema (fixed seed, a bounded number per operation); none may
answer 5xx and every documented answer must match its schema.

Figures (operations, examples, failures) are printed; run with ``-s`` to see them.
"""

from __future__ import annotations

import os
import time

import pytest

schemathesis = pytest.importorskip("schemathesis")
from hypothesis import HealthCheck, Phase, given, seed, settings  # noqa: E402
from hypothesis.errors import Unsatisfiable  # noqa: E402
from schemathesis import GenerationMode  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402
from schemathesis.specs.openapi.checks import response_schema_conformance  # noqa: E402

from tests.support.factories import make_machine  # noqa: E402
from tests.support.live_server import live_server, postgres_unavailable_reason  # noqa: E402

# per operation and generation mode; PostgreSQL gets fewer (the same code, another database under it):
# together about 60 s on a 2-core machine
EXAMPLES = {"sqlite": int(os.environ.get("SETUPCAM_FUZZ_EXAMPLES", "15")), "postgres": 8}
SEED = 17
# Signing out would end the session the run is authenticated with.
SKIP = {("POST", "/api/v1/auth/logout")}


@pytest.mark.slow
@pytest.mark.integration
@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_openapi_fuzz_finds_no_server_error_and_no_schema_violation(tmp_path, backend):
    if backend == "postgres" and postgres_unavailable_reason():
        pytest.skip(postgres_unavailable_reason())
    with live_server(tmp_path, backend, max_upload_mb=2, max_mesh_faces=20_000, load_example_library=False) as srv:
        with srv.client("admin") as c:
            make_machine(c, None)  # something for the ids to find: model 1, camera 1, machine 1
        auth = {"Authorization": f"Bearer {srv.tokens['admin']}"}  # a session token: survives key revocation
        schema = schemathesis.openapi.from_url(f"{srv.url}/openapi.json")
        operations, examples, failures = 0, 0, []
        statuses: dict[int, int] = {}
        t0 = time.monotonic()
        for result in schema.get_all_operations():
            op = result.ok()
            if (op.method.upper(), op.path) in SKIP:
                continue
            operations += 1
            for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
                strategy = op.as_strategy(generation_mode=mode)

                @seed(SEED)
                @settings(max_examples=EXAMPLES[backend], database=None, deadline=None, phases=[Phase.generate],
                          suppress_health_check=list(HealthCheck), derandomize=False)
                @given(case=strategy)
                def run(case) -> None:
                    nonlocal examples
                    examples += 1
                    response = case.call(base_url=srv.url, headers=auth, timeout=30)
                    statuses[response.status_code] = statuses.get(response.status_code, 0) + 1
                    try:
                        case.validate_response(response, checks=[not_a_server_error, response_schema_conformance],
                                               headers=auth)
                    except (Exception, BaseExceptionGroup) as exc:  # noqa: BLE001 - collected: all operations run
                        why = " | ".join(str(e).strip()[:300] for e in getattr(exc, "exceptions", [exc]))
                        failures.append(f"{op.method.upper()} {op.path} [{mode.value}] -> {response.status_code}: "
                                        f"{why}\n    {response.text[:300]}")

                try:
                    run()
                except Unsatisfiable:  # nothing to make invalid (an operation without parameters)
                    pass
        took = time.monotonic() - t0
    print(f"\nschemathesis ({backend}): {operations} operations, {examples} examples, {len(failures)} failures, {took:.0f} s; "
          f"answers: {dict(sorted(statuses.items()))}")
    assert not failures, "\n".join(failures[:40])
