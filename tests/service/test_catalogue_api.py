"""What ``GET /api/v1/tasks`` says of each installed task: how it holds its robot."""

from __future__ import annotations

from fastapi.testclient import TestClient

from adclient.plugins import catalogue


def test_each_task_says_whether_its_robot_is_fixed_and_whether_templates_may_use_it(
    api: TestClient,
) -> None:
    response = api.get("/api/v1/tasks")
    assert response.status_code == 200, response.text
    listed = {task["name"]: task for task in response.json()}
    assert listed["diagonal-gesture"]["fixed_base"] is True  # an arm bolted to the table
    assert listed["stand-up"]["fixed_base"] is False
    for name, spec in catalogue().tasks.items():
        assert listed[name]["fixed_base"] is spec.fixed_base, name
        assert listed[name]["templates"] is spec.templates, name
    assert any(task["templates"] for task in listed.values())
