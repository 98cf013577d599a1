# Sourced by the remote cache tests: starts nginx as the current user on 127.0.0.1 and a free
# port, storing under a folder of the test (WebDAV PUT, or read-only), and stops it.
#   start_nginx DIR STORE [readonly]   sets NGINX_PID, NGINX_PORT, NGINX_URL
#   stop_nginx
# Everything nginx writes (pid, logs, temp bodies) stays in DIR; no root needed (as root the
# workers stay root, so that they can write the test's folders).

free_port() {
  /usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# Waits until something accepts connections on 127.0.0.1:$1 (at most 10 s).
wait_port() {
  /usr/bin/python3 - "$1" <<'PY'
import socket, sys, time
for _ in range(200):
    try:
        socket.create_connection(("127.0.0.1", int(sys.argv[1])), timeout=0.2).close()
        sys.exit(0)
    except OSError:
        time.sleep(0.05)
sys.exit(1)
PY
}

start_nginx() {
  local dir=$1 store=$2 mode=${3:-dav}
  mkdir -p "$dir/logs" "$dir/tmp" "$store"
  NGINX_PORT=$(free_port)
  local user_line="" methods="dav_methods PUT;"
  if [ "$(id -u)" -eq 0 ]; then user_line="user root;"; fi
  if [ "$mode" = readonly ]; then methods="# read-only: PUT answers 405"; fi
  cat > "$dir/nginx.conf" <<CONF
daemon off;
$user_line
worker_processes 1;
pid $dir/nginx.pid;
error_log $dir/logs/error.log warn;
events { worker_connections 64; }
http {
  access_log $dir/logs/access.log;
  client_body_temp_path $dir/tmp/body;
  proxy_temp_path $dir/tmp/proxy;
  fastcgi_temp_path $dir/tmp/fastcgi;
  uwsgi_temp_path $dir/tmp/uwsgi;
  scgi_temp_path $dir/tmp/scgi;
  server {
    listen 127.0.0.1:$NGINX_PORT;
    root $store;
    location / {
      $methods
      create_full_put_path on;
      client_max_body_size 0;
    }
  }
}
CONF
  "${NGINX:-nginx}" -p "$dir" -c "$dir/nginx.conf" -e "$dir/logs/error.log" &
  NGINX_PID=$!
  NGINX_URL="http://127.0.0.1:$NGINX_PORT"
  if ! wait_port "$NGINX_PORT"; then
    echo "FAIL: nginx did not start:"; cat "$dir/logs/error.log"; return 1
  fi
}

stop_nginx() {
  if [ -n "${NGINX_PID:-}" ]; then
    kill "$NGINX_PID" 2>/dev/null || true
    wait "$NGINX_PID" 2>/dev/null || true
    NGINX_PID=""
  fi
}
