"""Thin rclpy nodes of the ambid graph; the numerical work lives in ``ambid``."""
