#!/usr/bin/env bash
# Prints deploy/prometheus/rules/humem.rules.yml as a Prometheus Operator
# PrometheusRule (the same rules, not a copy to keep in step):
#   deploy/kubernetes/monitoring/prometheusrule.sh | kubectl apply -f -
# Extra labels for the operator's ruleSelector: PROMETHEUSRULE_LABELS='release: kube-prometheus-stack'
set -euo pipefail
rules=$(cd "$(dirname "$0")/../../prometheus/rules" && pwd)/humem.rules.yml
cat <<YAML
apiVersion: monitoring.coreos.com/v1
kind: PrometheusRule
metadata:
  name: humem
  labels:
    app.kubernetes.io/name: humem
${PROMETHEUSRULE_LABELS:+    $PROMETHEUSRULE_LABELS
}spec:
YAML
sed -e '/^#/d' -e 's/^/  /' "$rules"
