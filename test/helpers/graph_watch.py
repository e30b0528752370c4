"""A process that watches the ROS graph of its domain (ROS_DOMAIN_ID): one line on stdout with
the sorted node names (comma-separated) each time they change, until its stdin closes. Run by
the tests that check a node leaves the graph when destroyed."""
import sys
import threading

import rclpy


def main() -> None:
    rclpy.init()
    node = rclpy.create_node("graph_watch")
    closed = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), closed.set()), daemon=True).start()
    last = None
    while not closed.is_set():
        names = ",".join(sorted(name for name, _ in node.get_node_names_and_namespaces()))
        if names != last:
            print(names, flush=True)
            last = names
        closed.wait(0.05)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
