#!/usr/bin/env bash
# Validates deploy/k8s/*.yaml against the Kubernetes JSON schemas with kubernetes-validate
# (from PyPI, installed into target/k8s-venv on first use).
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV=target/k8s-venv
KUBE_VERSION=${KUBE_VERSION:-1.31.0}
if [[ ! -x "$VENV/bin/kubernetes-validate" ]]; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q "kubernetes-validate==1.31.0"
fi
files=()
for f in deploy/k8s/*.yaml; do
  [[ "$(basename "$f")" == kustomization.yaml ]] || files+=("$f")
done
"$VENV/bin/kubernetes-validate" --strict --kubernetes-version "$KUBE_VERSION" "${files[@]}"
