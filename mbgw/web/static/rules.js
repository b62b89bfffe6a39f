// The gateway's own rules the pages check before asking (the gateway checks them again).
export const MIN_PASSWORD = 10;    // mbgw/web/passwords.py MIN_LENGTH
