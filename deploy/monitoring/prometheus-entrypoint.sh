#!/bin/sh
# Starts Prometheus on deploy/monitoring/prometheus.yml; with a farm token (TESSERA_TOKEN), the
# scrape carries it, read from a file only Prometheus can read.
set -eu
config=/etc/tessera/prometheus.yml
if [ -n "${TESSERA_TOKEN:-}" ]; then
  umask 077
  printf '%s' "$TESSERA_TOKEN" > /prometheus/token
  { cat "$config"; printf '    authorization:\n      type: Bearer\n      credentials_file: /prometheus/token\n'; } > /prometheus/prometheus.yml
  config=/prometheus/prometheus.yml
fi
exec prometheus --config.file="$config" --storage.tsdb.path=/prometheus --web.listen-address=0.0.0.0:9090 "$@"
