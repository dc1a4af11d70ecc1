#!/bin/bash
# The image's HEALTHCHECK: GET /healthz on the port of TERRASTREAM_BIND and exit 0 on a 200.
# The slim image has no curl, so it speaks HTTP/1.1 over bash's /dev/tcp.
set -eu
bind="${TERRASTREAM_BIND:-127.0.0.1:8080}"
port="${bind##*:}"
host="${bind%:*}"
host="${host#[}"
host="${host%]}"
case "$host" in
  "" | 0.0.0.0) host=127.0.0.1 ;;
  ::) host=::1 ;;
esac
exec 3<>"/dev/tcp/$host/$port"
printf 'GET /healthz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n' >&3
IFS=' ' read -r -t 4 _version status _ <&3
[ "$status" = 200 ]
