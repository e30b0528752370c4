# Hides the built control_msgs from a test's process (interfaces_build.without): as if never
# built.
raise ModuleNotFoundError("No module named 'control_msgs' (hidden by "
                          "test/helpers/without_interfaces)", name="control_msgs")
