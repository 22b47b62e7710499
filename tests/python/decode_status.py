"""A client in another language: decodes the coordinator's status and diagnostics of a team
with nothing but eclipse-zenoh and the standard library (no project code).

usage: decode_status.py ENDPOINT TEAM [TIMEOUT_S]
Prints one line per decoded message kind and exits 0 once both were seen; exits 1 (saying
what is missing) after TIMEOUT_S seconds.
"""
import json
import sys
import threading

import zenoh


def main():
    endpoint, team = sys.argv[1], sys.argv[2]
    timeout = float(sys.argv[3]) if len(sys.argv) > 3 else 30.0
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    seen = {}
    done = threading.Event()
    lock = threading.Lock()

    def on_sample(sample):
        key = str(sample.key_expr)
        encoding = str(sample.encoding)
        kind = key.rsplit("/", 1)[-1]
        try:
            msg = json.loads(sample.payload.to_bytes())
        except ValueError as e:
            print(f"{key}: not JSON ({encoding}): {e}", flush=True)
            return
        with lock:
            if kind in seen:
                return
            seen[kind] = (encoding, msg)
            if kind == "status":
                print(f"status encoding={encoding} mode={msg['mode']} ticks={msg['ticks']} members={msg['members']} version={msg['header']['version']}", flush=True)
            elif kind == "diagnostics":
                print(f"diagnostics encoding={encoding} tick={msg['header']['tick']} qp_status={msg['qp_status']} qp_solve_us={msg['qp_solve_us']} contacts={len(msg['contacts'])} grasp_slip={msg['grasp_slip']} fallback={msg['fallback']}", flush=True)
            if {"status", "diagnostics"} <= seen.keys():
                done.set()

    with zenoh.open(conf) as session:
        session.declare_subscriber(f"team/{team}/coordinator/*", on_sample)
        if not done.wait(timeout):
            missing = {"status", "diagnostics"} - seen.keys()
            print(f"after {timeout} s nothing decoded on team/{team}/coordinator/{{{','.join(sorted(missing))}}}", file=sys.stderr)
            sys.exit(1)


if __name__ == "__main__":
    main()
