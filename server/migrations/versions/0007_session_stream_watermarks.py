"""sessions: the newest gyroscope and magnetometer sample time received (NULL = none yet)

An upload whose gyroscope or magnetometer samples are not after the newest one the session already received
is refused with 422 (the engine would drop them without a word, as it refuses late accelerometer samples);
these columns let the server decide that from the row it reads anyway, before the engine runs. Sessions
started before this revision get NULL: their next upload is taken as before and sets them.

Revision ID: 0007
Revises: 0006
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("sessions") as b:
        b.add_column(sa.Column("gyr_newest_ns", sa.BigInteger(), nullable=True))
        b.add_column(sa.Column("mag_newest_ns", sa.BigInteger(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("sessions") as b:
        b.drop_column("mag_newest_ns")
        b.drop_column("gyr_newest_ns")
