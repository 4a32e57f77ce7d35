"""The part of kustomize that deploy/k8s uses, in Python, so the manifests can be rendered
and checked where no ``kustomize`` or ``kubectl`` is installed.

Supported: ``resources`` (files and folders), ``namespace``, ``images``, and ``patches``
either as strategic-merge documents (a file or inline; lists of objects with a ``name``
merge by name, the patch's entries first, then the rest in their order, as kustomize
does; other lists are replaced) or as JSON 6902 operations (add, replace, remove) on a
``target``. Anything else in a kustomization is refused, so a manifest never goes
unchecked because this renderer skipped a feature. tests/test_k8s_manifests.py compares
its output with ``kubectl kustomize`` where kubectl is installed.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

Resource = dict[str, Any]

SUPPORTED = {"apiVersion", "kind", "resources", "namespace", "images", "patches"}
CLUSTER_SCOPED = {
    "Namespace",
    "ClusterRole",
    "ClusterRoleBinding",
    "CustomResourceDefinition",
    "PersistentVolume",
    "StorageClass",
    "PriorityClass",
    "IngressClass",
}


class Unsupported(ValueError):
    pass


def load_documents(path: Path) -> list[Resource]:
    return [doc for doc in yaml.safe_load_all(path.read_text()) if doc]


def render(folder: Path) -> list[Resource]:
    """The resources ``kustomize build folder`` makes (in the order they are declared)."""
    kustomization = yaml.safe_load((folder / "kustomization.yaml").read_text())
    unknown = set(kustomization) - SUPPORTED
    if unknown:
        raise Unsupported(f"{folder}: kustomization fields not rendered here: {sorted(unknown)}")
    resources: list[Resource] = []
    for entry in kustomization.get("resources", []):
        path = (folder / entry).resolve()
        resources += render(path) if path.is_dir() else load_documents(path)
    for patch in kustomization.get("patches", []):
        apply_patch(folder, patch, resources)
    for image in kustomization.get("images", []):
        for resource in resources:
            set_image(resource, image)
    namespace = kustomization.get("namespace")
    if namespace:
        for resource in resources:
            if resource["kind"] not in CLUSTER_SCOPED:
                resource["metadata"]["namespace"] = namespace
    return resources


def matches(resource: Resource, target: dict[str, str]) -> bool:
    unknown = set(target) - {"group", "version", "kind", "name"}
    if unknown:
        raise Unsupported(f"patch target selectors not rendered here: {sorted(unknown)}")
    group, _, version = resource["apiVersion"].rpartition("/")
    found = {"group": group, "version": version, **resource, **resource["metadata"]}
    return all(found.get(key) == value for key, value in target.items())


def apply_patch(folder: Path, patch: dict[str, Any], resources: list[Resource]) -> None:
    unknown = set(patch) - {"path", "patch", "target"}
    if unknown:
        raise Unsupported(f"patch fields not rendered here: {sorted(unknown)}")
    body = (folder / patch["path"]).read_text() if "path" in patch else patch["patch"]
    document = yaml.safe_load(body)
    if isinstance(document, list):
        targets = [r for r in resources if matches(r, patch["target"])]
        for resource in targets:
            json6902(resource, document)
    else:
        target = patch.get("target") or {
            "kind": document["kind"],
            "name": document["metadata"]["name"],
        }
        targets = [r for r in resources if matches(r, target)]
        for resource in targets:
            merged = strategic_merge(resource, document)
            resource.clear()
            resource.update(merged)
    if not targets:
        raise ValueError(f"{folder}: a patch matches no resource: {patch}")


def strategic_merge(original: Any, patch: Any) -> Any:
    if isinstance(original, dict) and isinstance(patch, dict):
        merged = dict(original)
        for key, value in patch.items():
            if value is None:
                merged.pop(key, None)
            else:
                merged[key] = strategic_merge(original[key], value) if key in original else value
        return merged
    if isinstance(original, list) and isinstance(patch, list) and _named(original + patch):
        by_name = {item["name"]: item for item in original}
        patched = [strategic_merge(by_name.get(i["name"], {}), i) for i in patch]
        names = {item["name"] for item in patch}
        return patched + [item for item in original if item["name"] not in names]
    return copy.deepcopy(patch)


def _named(items: list[Any]) -> bool:
    return bool(items) and all(isinstance(item, dict) and "name" in item for item in items)


def _pointer(path: str) -> list[str]:
    return [part.replace("~1", "/").replace("~0", "~") for part in path.split("/")[1:]]


def json6902(resource: Resource, operations: list[dict[str, Any]]) -> None:
    for operation in operations:
        *parents, last = _pointer(operation["path"])
        node: Any = resource
        for part in parents:
            node = node[int(part)] if isinstance(node, list) else node[part]
        op = operation["op"]
        if isinstance(node, list):
            index = len(node) if last == "-" else int(last)
            if op == "add":
                node.insert(index, operation["value"])
            elif op == "replace":
                node[index] = operation["value"]
            elif op == "remove":
                del node[index]
            else:
                raise Unsupported(f"JSON patch op {op!r}")
        elif op in ("add", "replace"):
            if op == "replace" and last not in node:
                raise KeyError(f"replace of a missing path {operation['path']}")
            node[last] = operation["value"]
        elif op == "remove":
            del node[last]
        else:
            raise Unsupported(f"JSON patch op {op!r}")


def split_image(image: str) -> tuple[str, str | None]:
    """``registry/name:tag`` as (``registry/name``, ``tag``); a digest stays in the name."""
    if "@" in image:
        return image, None
    name, _, tag = image.rpartition(":")
    if name and "/" not in tag:
        return name, tag
    return image, None


def set_image(node: Any, image: dict[str, str]) -> None:
    """Every container's and init container's ``image`` named ``image["name"]``."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key in ("containers", "initContainers") and isinstance(value, list):
                for container in value:
                    name, tag = split_image(container.get("image", ""))
                    if name == image["name"]:
                        new_name = image.get("newName", name)
                        new_tag = image.get("newTag", tag)
                        container["image"] = f"{new_name}:{new_tag}" if new_tag else new_name
            set_image(value, image)
    elif isinstance(node, list):
        for item in node:
            set_image(item, image)
