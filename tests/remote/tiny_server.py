#!/usr/bin/python3
"""A tiny HTTP store for the remote cache's unit tests (Python's http.server, one thread a request).

  tiny_server.py PORT_FILE ROOT [--mode store|hang|no-put] [--require-header 'Name: value']
                                [--require-basic USER:PASS]

Binds 127.0.0.1 on a free port and writes the port to PORT_FILE (atomically) once it listens.
store:  GET/HEAD answer ROOT/<path> (404 when absent), PUT writes it (creating folders), 201.
no-put: as store, but PUT answers 405 (a read-only server).
hang:   accepts connections and never answers.
--require-header / --require-basic: requests without that header (or those Basic credentials)
get 401.
"""
import argparse
import base64
import os
import socket
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("port_file")
    ap.add_argument("root")
    ap.add_argument("--mode", default="store", choices=["store", "hang", "no-put"])
    ap.add_argument("--require-header")
    ap.add_argument("--require-basic")
    a = ap.parse_args()

    def publish(port):
        tmp = a.port_file + ".tmp"
        with open(tmp, "w") as f:
            f.write(str(port))
        os.rename(tmp, a.port_file)

    if a.mode == "hang":
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        s.listen(16)
        publish(s.getsockname()[1])
        held = []
        while True:
            c, _ = s.accept()
            held.append(c)  # never answered, never closed

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):
            pass

        def allowed(self):
            if a.require_header:
                name, value = a.require_header.split(":", 1)
                if self.headers.get(name.strip()) != value.strip():
                    return False
            if a.require_basic:
                want = "Basic " + base64.b64encode(a.require_basic.encode()).decode()
                if self.headers.get("Authorization") != want:
                    return False
            return True

        def answer(self, code, body=b""):
            self.send_response(code)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)

        def path_on_disk(self):
            p = os.path.normpath(self.path.split("?")[0]).lstrip("/")
            if p.startswith(".."):
                return None
            return os.path.join(a.root, p)

        def do_GET(self):
            if not self.allowed():
                return self.answer(401)
            p = self.path_on_disk()
            if not p or not os.path.isfile(p):
                return self.answer(404)
            with open(p, "rb") as f:
                self.answer(200, f.read())

        do_HEAD = do_GET

        def do_PUT(self):
            n = int(self.headers.get("Content-Length", "0"))
            body = self.rfile.read(n)
            if not self.allowed():
                return self.answer(401)
            if a.mode == "no-put":
                return self.answer(405)
            p = self.path_on_disk()
            if not p:
                return self.answer(400)
            os.makedirs(os.path.dirname(p), exist_ok=True)
            with open(p + ".part", "wb") as f:
                f.write(body)
            os.rename(p + ".part", p)
            self.answer(201)

    srv = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    publish(srv.server_address[1])
    srv.serve_forever()


if __name__ == "__main__":
    main()
