# Hides the built tf2_msgs from a test's process (interfaces_build.without): as if never
# built.
raise ModuleNotFoundError("No module named 'tf2_msgs' (hidden by "
                          "test/helpers/without_interfaces)", name="tf2_msgs")
